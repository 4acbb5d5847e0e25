"""Per-pass time of the disk method's tree pass on a ~700k-vertex scene.

Times every ``_Pass.sums`` call (one pass over every receiver bucket) of
``occlusion_passes`` with three passes: pass 1 (binned, keeps its direction bins) and the
gated later passes. To compare kernel changes, run it from two checkouts
(``PYTHONPATH=<checkout>``), interleaved, with a warm numba cache (a first run compiles).

Usage: ``python bench/bench_treepass.py [--scene spheres|bunny] [--repeats N] [--vertices N]
[--measure cosine|uniform]``.
"""

from __future__ import annotations

import argparse
import time

from aobake.methods.bunnell import BunnellOptions, build_elements, build_tree, occlusion_passes
from aobake.methods.bunnell import passes as P

import common


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", choices=("spheres", "bunny"), default="spheres")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--vertices", type=int, default=700_000)
    parser.add_argument("--measure", choices=("cosine", "uniform"), default="cosine")
    args = parser.parse_args()
    build = common.spheres_on_ground if args.scene == "spheres" else common.bunny_on_ground
    surface, _ = build(args.vertices)
    elements = build_elements(surface)
    tree = build_tree(elements)
    times = []
    plain = P._Pass.sums

    def timed_sums(self, *a, **kw):
        t0 = time.perf_counter()
        out = plain(self, *a, **kw)
        times.append(time.perf_counter() - t0)
        return out

    P._Pass.sums = timed_sums
    for _ in range(args.repeats):
        times.clear()
        occlusion_passes(elements, tree, BunnellOptions(passes=3, measure=args.measure))
        print(f"{args.scene} {args.measure} n={elements.n_vertices} per pass s: "
              + " ".join(f"{t:.3f}" for t in times), flush=True)


if __name__ == "__main__":
    main()
