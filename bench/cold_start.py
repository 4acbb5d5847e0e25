"""The first run's goals: a cold ``aobake bake --method bunnell`` of a ~10k-vertex mesh in
<= 30 s and a cold ``aobake field`` in <= 20 s, on 2 cores (docs/first-run.md).

Runs each command as a user does (the ``aobake`` console script next to this Python, else
``python -m aobake``: the two differ in stack depth, which once decided 20 s of system
time) in a fresh process with an empty numba cache, ``--repeats`` times, round-robin,
and prints wall seconds, user + system CPU of the process and its helpers (waited-for
children), minor page faults (~0.3 M normal; millions: see docs/first-run.md) and the
command's summary. Wall times mean something only on an idle machine; the load average
is printed with each run.

Usage: ``PYTHONPATH=. python bench/cold_start.py [--repeats N] [--vertices N]
[--only bake|field]``.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import common

GOALS = {"bake": 30.0, "field": 20.0}


def aobake_command() -> list[str]:
    """The console script beside this interpreter, else ``python -m aobake``."""
    script = Path(sys.executable).with_name("aobake")
    return [str(script)] if script.exists() else [sys.executable, "-m", "aobake"]


def cold_run(args: list[str], cwd: Path) -> dict:
    """One run of ``aobake ARGS`` from an empty numba cache."""
    cache = tempfile.mkdtemp(prefix="aobake-cold-")
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(common.ROOT), env.get("PYTHONPATH")) if p)
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run(aobake_command() + args, cwd=cwd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    shutil.rmtree(cache, ignore_errors=True)
    if out.returncode != 0:
        raise SystemExit(f"aobake {' '.join(args)} failed:\n{out.stderr}")
    # the summary's "in X s (+ Y s compiling kernels, first run only)"
    found = re.findall(r" in ([0-9.]+) s.*?\(\+ ([0-9.]+) s compiling", out.stderr)
    return {
        "wall": wall,
        "user": after.ru_utime - before.ru_utime,
        "sys": after.ru_stime - before.ru_stime,
        "faults": after.ru_minflt - before.ru_minflt,
        "load": load,
        "summary": f"{found[-1][0]} s + {found[-1][1]} s compiling" if found else "",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--vertices", type=int, default=10_000)
    parser.add_argument("--only", choices=sorted(GOALS), default=None)
    args = parser.parse_args()
    from aobake.pipeline import _write_plain_ply

    work = Path(tempfile.mkdtemp(prefix="aobake-cold-start-"))
    scene, desc = common.bunny_on_ground(args.vertices)
    mesh = work / "bunny10k.ply"
    _write_plain_ply(mesh, scene.positions, scene.faces)
    commands = {
        "bake": ["bake", str(mesh), "-o", str(work / "out.ply"), "--method", "bunnell"],
        "field": ["field", str(common.DATA_DIR / "bunny.ply"), "-o", str(work / "f.npz")],
    }
    names = [args.only] if args.only else list(GOALS)
    rows = []
    for _ in range(args.repeats):
        for name in names:
            r = cold_run(commands[name], work)
            rows.append(
                [
                    name,
                    f"{r['wall']:.1f}",
                    f"{GOALS[name]:.0f}",
                    f"{r['user']:.1f} + {r['sys']:.1f}",
                    f"{r['faults'] / 1e6:.2f} M",
                    f"{r['load']:.1f}",
                    r["summary"],
                ]
            )
            print(" | ".join(rows[-1]), flush=True)
    common.print_table(
        f"cold first runs ({' '.join(aobake_command()[-2:])}; bake: {desc}, {scene.n_vertices} vertices)",
        ["command", "wall s", "goal s", "user + sys s", "minor faults", "load", "reported"],
        rows,
        note="empty numba cache per run; CPU and faults include the helper processes",
    )
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
