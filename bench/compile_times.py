"""What the first run compiles: per-kernel numba compile seconds from a cold cache.

Runs, in a fresh numba cache directory (unless ``--cache DIR``), what a new user's first
commands run: a disk-method bake of a ~10k-vertex scene, ``aobake field`` with its
defaults, and (``--all``) the ray method and a bake with ``--field``. numba's
``numba:compile`` events (one per specialisation actually compiled) are recorded per
kernel: self seconds (its own compile, callees compiled on the way excluded; wall and
the compiling thread's CPU), inclusive seconds, and how many specialisations. Prints one
table per stage, largest first.

Usage: ``python bench/compile_times.py [--vertices N] [--stages bunnell,field] [--all]
[--cache DIR] [--top K]``. Run it from the checkout to measure (``PYTHONPATH=...``).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections import defaultdict


class KernelTimes:
    """A ``numba:compile`` listener (registered through :func:`listener`): seconds per
    dispatcher, nested compiles split out."""

    def __init__(self):
        self.stack = []  # [name, start, cpu start, nested seconds, nested cpu seconds]
        self.self_s = defaultdict(float)
        self.self_cpu = defaultdict(float)
        self.incl_s = defaultdict(float)
        self.count = defaultdict(int)

    def notify(self, event):
        if event.is_start:
            disp = event.data["dispatcher"]
            name = f"{disp.py_func.__module__.removeprefix('aobake.kernels.')}.{disp.py_func.__name__}"
            self.stack.append([name, time.perf_counter(), time.thread_time(), 0.0, 0.0])
        elif event.is_end:
            name, start, cpu_start, nested, nested_cpu = self.stack.pop()
            total = time.perf_counter() - start
            cpu = time.thread_time() - cpu_start
            self.incl_s[name] += total
            self.self_s[name] += total - nested
            self.self_cpu[name] += cpu - nested_cpu
            self.count[name] += 1
            if self.stack:
                self.stack[-1][3] += total
                self.stack[-1][4] += cpu

    def clear(self):
        self.self_s.clear()
        self.self_cpu.clear()
        self.incl_s.clear()
        self.count.clear()


def listener(times: KernelTimes):
    """``times`` as a numba Listener (numba is imported only once the cache is set)."""
    from numba.core import event

    class Adapter(event.Listener):
        def on_start(self, ev):
            times.notify(ev)

        def on_end(self, ev):
            times.notify(ev)

    return Adapter()


def _stages(n_vertices: int, names: list[str]):
    """(name, description, function) of every stage asked for, in order."""
    import numpy as np

    from aobake.methods import run

    import common

    scene, desc = common.bunny_on_ground(n_vertices)
    bunny = common.load_surface(common.DATA_DIR / "bunny.ply")
    out = {}

    def bunnell():
        run("bunnell", scene, {}, None)

    def embree():
        run("embree", scene, {"n_rays": 16}, None)

    field_holder = {}

    def field():
        from aobake.methods.fields import fit_field

        field_holder["f"] = fit_field(bunny)

    def apply_field():
        from aobake.methods.fields import fields_ao

        f = field_holder.get("f")
        if f is None:
            from aobake.methods.fields import fit_field

            f = fit_field(bunny, resolution=4, radial_samples=8)
        p = scene.positions[:1000]
        fields_ao([f], p, np.tile([0.0, 1.0, 0.0], (len(p), 1)), transforms=[None])

    out["bunnell"] = (f"bake --method bunnell, {desc} ({scene.n_vertices} vertices)", bunnell)
    out["field"] = ("aobake field data/bunny.ply (defaults)", field)
    out["embree"] = (f"bake --method embree --rays 16, {scene.n_vertices} vertices", embree)
    out["apply"] = ("bake --field (evaluate a field at 1000 points)", apply_field)
    return [(k, *out[k]) for k in names]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vertices", type=int, default=10_000)
    parser.add_argument("--stages", default="bunnell,field")
    parser.add_argument("--all", action="store_true", help="stages bunnell,field,embree,apply")
    parser.add_argument("--cache", default=None, help="numba cache directory (default: a new empty one)")
    parser.add_argument("--top", type=int, default=12, help="kernels listed per stage")
    args = parser.parse_args()
    if "numba" in sys.modules:
        raise SystemExit("numba already imported: the cache directory cannot be set")
    cache = args.cache or tempfile.mkdtemp(prefix="aobake-numba-")
    os.environ["NUMBA_CACHE_DIR"] = cache
    import numba
    from numba.core import event

    import common

    names = "bunnell,field,embree,apply" if args.all else args.stages
    print(f"numba {numba.__version__}, cache {cache}, {numba.config.NUMBA_NUM_THREADS} threads")
    times = KernelTimes()
    event.register("numba:compile", listener(times))
    summary = []
    for key, desc, fn in _stages(args.vertices, names.split(",")):
        times.clear()
        t0 = time.perf_counter()
        fn()
        wall = time.perf_counter() - t0
        outer = sum(times.self_s.values())
        cpu = sum(times.self_cpu.values())
        rows = sorted(times.self_s, key=times.self_s.get, reverse=True)
        table = [
            [name, times.count[name], f"{times.self_s[name]:.1f}", f"{times.self_cpu[name]:.1f}",
             f"{times.incl_s[name]:.1f}"]
            for name in rows[: args.top]
        ]
        rest = rows[args.top:]
        if rest:
            table.append([f"({len(rest)} others)", sum(times.count[n] for n in rest),
                          f"{sum(times.self_s[n] for n in rest):.1f}",
                          f"{sum(times.self_cpu[n] for n in rest):.1f}", ""])
        common.print_table(
            f"{key}: {desc}",
            ["kernel", "compiles", "self s", "self CPU s", "inclusive s"],
            table,
            note=f"wall {wall:.1f} s, of it compiling {outer:.1f} s (CPU {cpu:.1f} s) "
            f"({sum(times.count.values())} specialisations)",
        )
        summary.append([key, f"{wall:.1f}", f"{outer:.1f}", f"{cpu:.1f}", sum(times.count.values())])
    common.print_table("summary (cold cache)", ["stage", "wall s", "compile s", "compile CPU s", "specialisations"],
                       summary, note="CPU: the compiling thread's own time (compiles run in one "
                       "thread), less sensitive to other load on the machine than wall time.")


if __name__ == "__main__":
    main()
