"""Adaptive sampling (--tolerance) against fixed ray counts: rays per vertex, RMSE, and
the share of early-stopped vertices that are really within the tolerance.

Run: ``python bench/adaptive_embree.py`` (about a minute on 2 cores).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aobake.io import load_mesh
from aobake.methods.embree import embree_ao
from aobake.testing import scenes

ROOT = Path(__file__).resolve().parents[1]

SETTINGS = [
    {"n_rays": 64},
    {"n_rays": 256},
    {"n_rays": 1024},
    {"n_rays": 1024, "tolerance": 0.05},
    {"n_rays": 1024, "tolerance": 0.02},
    {"n_rays": 1024, "tolerance": 0.01},
]


def main() -> None:
    meshes = [
        ("sphere_on_ground (4k)", scenes.sphere_on_ground(0.5, 4, cells=40)[0]),
        ("bunny", load_mesh(ROOT / "data" / "bunny.ply")),
        ("box_stack", load_mesh(ROOT / "data" / "box_stack.ply")),
    ]
    print("| scene | setting | rays/vertex | RMSE | p99 | early stops within tol |")
    print("|---|---|---:|---:|---:|---:|")
    for name, s in meshes:
        ref = embree_ao(s, n_rays=8192, seed=99).ao
        for kw in SETTINGS:
            r = embree_ao(s, seed=1, **kw)
            err = r.ao - ref
            stopped = r.rays < kw["n_rays"]
            tol = kw.get("tolerance")
            within = f"{np.mean(np.abs(err[stopped]) <= tol):.3f}" if tol and stopped.any() else ""
            label = f"≤{kw['n_rays']} tol {tol}" if tol else f"{kw['n_rays']} rays"
            print(
                f"| {name} | {label} | {r.rays.mean():.0f} | {np.sqrt(np.mean(err**2)):.4f} | "
                f"{np.percentile(np.abs(err), 99):.4f} | {within} |"
            )


if __name__ == "__main__":
    main()
