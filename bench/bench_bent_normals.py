"""What ``--bent-normals`` costs: the same embree bake with and without it, timed in one
run (best of ``REPEATS`` each, interleaved), and the ratio.

Run: ``python bench/bench_bent_normals.py [MESH] [RAYS]`` (default data/bunny.ply, 1024).
The escaping directions are summed from the AO rays themselves, so the extra work is one
pass over each chunk's directions; ``ao`` is bit-identical either way (checked here too).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from aobake.io import load_mesh
from aobake.methods.embree import embree_ao

REPEATS = 5


def main(mesh: str = "data/bunny.ply", rays: int = 1024) -> None:
    surface = load_mesh(mesh)
    embree_ao(surface, n_rays=16, bent_normals=True)  # compile outside the timing
    best = {False: float("inf"), True: float("inf")}
    results = {}
    for _ in range(REPEATS):
        for bent in (False, True):
            t0 = time.perf_counter()
            results[bent] = embree_ao(surface, n_rays=rays, seed=0, bent_normals=bent)
            best[bent] = min(best[bent], time.perf_counter() - t0)
    assert np.array_equal(results[False].ao, results[True].ao)
    print(f"{mesh}: {surface.n_vertices} vertices, {rays} rays")
    print(f"| without | with --bent-normals | ratio |\n|---|---|---|\n"
          f"| {best[False]:.3f} s | {best[True]:.3f} s | {best[True] / best[False]:.2f} |")  # fmt: skip


if __name__ == "__main__":
    main(*(sys.argv[1:2]), *(int(a) for a in sys.argv[2:3]))
