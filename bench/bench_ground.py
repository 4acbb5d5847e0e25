"""The ground plane (``--ground``): what it costs and how accurate each method is with it.

    python bench/bench_ground.py

Per scene, resting on the plane (auto) along its up axis: Embree 256 rays without the
plane, with the analytic plane and with an explicit plane of two triangles (as wide as
20 bounding radii: what a user would model), round-robin in one run; the disk method
without and with the plane; and the RMSE of each against Embree 1024 rays (seed 1) of
the same scene.
"""

from __future__ import annotations

import numpy as np

from aobake.ground import resolve_ground
from aobake.mesh import surface_from_arrays
from aobake.methods.bunnell import bunnell_ao
from aobake.methods.embree import embree_ao

from common import DATA_DIR, fmt_s, interleaved, load_surface, print_table, rmse

SCENES = (
    ("bunny.ply", "Y"),
    ("sphere_on_ground.ply", "Z"),
    ("box_stack.ply", "Y"),
    ("bunny.ply x3", "Y"),
)


def scene(name: str):
    """A bundled mesh; "NAME xK": loop-subdivided K times (the timing scene: 117k vertices)."""
    file, _, times = name.partition(" x")
    s = load_surface(DATA_DIR / file)
    if not times:
        return s
    import trimesh

    v, f = trimesh.remesh.subdivide_loop(s.positions, s.faces, iterations=int(times))
    return surface_from_arrays(v, f)


def with_floor(surface, ground, radii: float = 20.0):
    """``surface`` plus a square of two triangles at the plane, ``radii`` bounding radii wide."""
    axis = ground.axis
    lo, hi = surface.positions.min(axis=0), surface.positions.max(axis=0)
    centre = 0.5 * (lo + hi)
    half = radii * 0.5 * float(np.linalg.norm(hi - lo))
    a, b = [k for k in range(3) if k != axis]
    quad = np.tile(centre, (4, 1))
    quad[:, axis] = ground.height
    for row, (sa, sb) in enumerate(((-1, -1), (1, -1), (1, 1), (-1, 1))):
        quad[row, a] += sa * half
        quad[row, b] += sb * half
    normal = np.zeros(3)
    normal[axis] = 1.0
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    e = np.cross(quad[1] - quad[0], quad[2] - quad[0])
    if e @ normal < 0:
        faces = faces[:, ::-1]
    n = surface.n_vertices
    return surface_from_arrays(
        np.vstack([surface.positions, quad]),
        np.vstack([surface.faces, faces + n]),
        np.vstack([surface.normals, np.tile(normal, (4, 1))]),
    )


def contenders(s, g, floor) -> dict:
    """What is timed on one scene, round-robin."""
    n = s.n_vertices
    return {
        "embree": lambda: embree_ao(s, n_rays=256).ao,
        "embree ground": lambda: embree_ao(s, n_rays=256, ground=g).ao,
        "embree 2 triangles": lambda: embree_ao(floor, n_rays=256).ao[:n],
        "bunnell": lambda: bunnell_ao(s),
        "bunnell ground": lambda: bunnell_ao(s, ground=g),
    }


def main() -> None:
    rows = []
    for name, up in SCENES:
        s = scene(name)
        g = resolve_ground("auto", s.positions, up)
        floor = with_floor(s, g)
        n = s.n_vertices
        reference = embree_ao(s, n_rays=1024, seed=1, ground=g).ao
        plain_reference = embree_ao(s, n_rays=1024, seed=1).ao
        t = interleaved(contenders(s, g, floor), repeats=3)
        rows.append(
            [
                f"{name} ({n}, up {up})",
                f"{fmt_s(t['embree'].seconds)} / {fmt_s(t['embree ground'].seconds)} / "
                f"{fmt_s(t['embree 2 triangles'].seconds)}",
                f"{rmse(t['embree ground'].result, reference):.4f}",
                f"{rmse(t['embree 2 triangles'].result, reference):.4f}",
                f"{fmt_s(t['bunnell'].seconds)} / {fmt_s(t['bunnell ground'].seconds)}",
                f"{rmse(t['bunnell'].result, plain_reference):.4f}",
                f"{rmse(t['bunnell ground'].result, reference):.4f} "
                f"({np.mean(t['bunnell ground'].result - reference):+.4f})",
                f"{rmse(plain_reference, reference):.3f}",
            ]
        )
    print_table(
        "Ground plane (auto): time and RMSE against Embree 1024 rays with the plane",
        [
            "scene",
            "embree 256: none / ground / 2 triangles",
            "ground RMSE",
            "2 triangles RMSE",
            "bunnell: none / ground",
            "bunnell RMSE, no plane (vs its own ref)",
            "bunnell ground RMSE (bias)",
            "what the plane changes (RMSE)",
        ],
        rows,
    )


if __name__ == "__main__":
    main()
