"""Per-pass time of the disk method's tree pass on a ~700k-vertex scene.

Times every ``_Pass.sums`` call (one pass over every receiver bucket) of
``occlusion_passes(passes=3)``: pass 1 (binned, keeps its direction bins) and the gated
later passes. Run it against two checkouts (``PYTHONPATH=<checkout>``), interleaved, to
compare kernel changes; the numba cache should be warm (a first run compiles).

Usage: ``python bench/bench_treepass.py [--scene spheres|bunny] [--repeats N]``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import common  # noqa: E402


def disk_module():
    """The disk method's wrapper module, wherever this checkout keeps it."""
    for name in ("aobake.methods.bunnell", "aobake.bunnell"):
        try:
            module = importlib.import_module(name)
        except ImportError:
            continue
        if hasattr(module, "_Pass"):
            return module
    raise ImportError("no disk method module with _Pass")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", choices=("spheres", "bunny"), default="spheres")
    parser.add_argument("--repeats", type=int, default=1)
    args = parser.parse_args()
    B = disk_module()
    build = common.spheres_on_ground if args.scene == "spheres" else common.bunny_on_ground
    surface, _ = build(700_000)
    elements = B.build_elements(surface)
    tree = B.build_tree(elements)
    times = []
    plain = B._Pass.sums

    def timed_sums(self, *a, **kw):
        t0 = time.perf_counter()
        out = plain(self, *a, **kw)
        times.append(time.perf_counter() - t0)
        return out

    B._Pass.sums = timed_sums
    for _ in range(args.repeats):
        times.clear()
        B.occlusion_passes(elements, tree, passes=3)
        print(f"{args.scene} n={elements.n_vertices} per pass s: "
              + " ".join(f"{t:.3f}" for t in times), flush=True)


if __name__ == "__main__":
    main()
