"""Benchmark of the disk method (aobake.bunnell): time per pass and hierarchy error.

Prints tables measured in one run (not a test; no assertions):

1. hierarchy: for ~100k and ~700k vertex scenes (spheres on a ground grid), build time,
   time of pass 1 and pass 2, and RMSE / p99 / max of pass-1 occlusion against the exact
   O(n^2) sum on a random subset of receivers, for several theta;
2. leaf size at the default theta (~100k scene);
3. scaling: time per pass for n, 4n and 16n vertices (goal about n log n);
4. against a ray-traced reference (Embree, 1024 rays; skipped if it does not import) on
   small hard scenes: exact sums for passes 1-4 and the pass combinations, and the tree
   at a few theta, to choose the defaults.

Usage: ``python bench/bench_bunnell.py [--quick] [--threads N] [--sections 1234]``.
Timings are wall-clock seconds with the given numba thread count; the machine's load
matters, so compare rows of one run, not runs of different days.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

from aobake import bunnell as B
from aobake.kernels import bunnell as K
from aobake.mesh import Part, Surface, surface_from_arrays

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def grid(cells: int, half: float, z: float):
    u = np.linspace(-half, half, cells + 1)
    x, y = np.meshgrid(u, u, indexing="ij")
    positions = np.c_[x.ravel(), y.ravel(), np.full(x.size, z)]
    idx = np.arange(x.size).reshape(x.shape)
    a, b, c, d = (
        idx[:-1, :-1].ravel(),
        idx[1:, :-1].ravel(),
        idx[1:, 1:].ravel(),
        idx[:-1, 1:].ravel(),
    )
    return positions, np.r_[np.c_[a, b, c], np.c_[a, c, d]].astype(np.int64)


def spheres_on_ground(cells: int, subdivisions: int, n_spheres: int) -> Surface:
    """``n_spheres`` unit icospheres in a row, touching a ground grid of cells^2 quads."""
    meshes = [grid(cells, 1.5 * n_spheres, -1.0)]
    for k in range(n_spheres):
        m = trimesh.creation.icosphere(subdivisions=subdivisions)
        meshes.append(
            (np.asarray(m.vertices) + [2.2 * (k - (n_spheres - 1) / 2), 0, 0], np.asarray(m.faces))
        )
    positions, faces, parts, v0, f0 = [], [], [], 0, 0
    for k, (p, f) in enumerate(meshes):
        positions.append(p)
        faces.append(f + v0)
        counts = np.full(len(f), 3, dtype=np.int64)
        parts.append(
            Part(f"part{k}", v0, v0 + len(p), f0, f0 + len(f), counts, f.reshape(-1).copy())
        )
        v0 += len(p)
        f0 += len(f)
    s = surface_from_arrays(np.concatenate(positions), np.concatenate(faces))
    return Surface(s.positions, s.faces, s.normals, tuple(parts), "spheres_on_ground")


def timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def exact_subset(elements, subset, threads):
    """Exact pass-1 occlusion at ``subset`` receivers (brute-force kernel on a chunk)."""
    emitters = B.pack_emitters(elements, elements.emitter_index)
    receivers = K.Receivers(elements.positions, elements.normals)
    out = np.zeros(elements.n_vertices)
    with B.numba_threads(threads):
        K.brute_force_pass(emitters, receivers, subset, K.MEASURE_COSINE, np.inf, out)
    return np.clip(out[subset], 0.0, 1.0)


def errors(approx, exact):
    e = np.abs(approx - exact)
    return np.sqrt(np.mean(e**2)), np.quantile(e, 0.99), e.max()


def warm_up(threads):
    s = spheres_on_ground(8, 1, 1)
    B.bunnell_ao(s, passes=2, threads=threads)
    B.bunnell_ao(s, passes=1, exact=True, threads=threads)


def section_hierarchy(scenes, thetas, threads, n_check):
    print("\n## 1. Hierarchy: time per pass and error of pass 1 against the exact sum")
    print(
        f"(error on {n_check} random receivers; leaf size {B.DEFAULT_LEAF_SIZE}; "
        f"{threads} threads)\n"
    )
    print("| n | build s | theta | pass 1 s | pass 2 s | RMSE | p99 | max |")
    print("|---|---|---|---|---|---|---|---|")
    for surface in scenes:
        (elements, t_el) = timed(B.build_elements, surface)
        tree, t_tree = timed(B.build_tree, elements)
        subset = np.sort(
            np.random.default_rng(0).choice(surface.n_vertices, n_check, replace=False)
        )
        exact = exact_subset(elements, subset, threads)
        for theta in thetas:
            occ1, t1 = timed(
                B.occlusion_passes, elements, tree, passes=1, theta=theta, threads=threads
            )
            _, t12 = timed(
                B.occlusion_passes, elements, tree, passes=2, theta=theta, threads=threads
            )
            rmse, p99, worst = errors(occ1[0][subset], exact)
            print(
                f"| {surface.n_vertices} | {t_el + t_tree:.2f} | {theta:g} | {t1:.2f} "
                f"| {t12 - t1:.2f} "
                f"| {rmse:.4f} | {p99:.4f} | {worst:.4f} |"
            )


def section_leaf(surface, leaf_sizes, threads, n_check):
    print(f"\n## 2. Leaf size at theta = {B.DEFAULT_THETA:g} (n = {surface.n_vertices})\n")
    print("| leaf | nodes | build s | pass 1 s | RMSE | max |")
    print("|---|---|---|---|---|---|")
    elements = B.build_elements(surface)
    subset = np.sort(np.random.default_rng(0).choice(surface.n_vertices, n_check, replace=False))
    exact = exact_subset(elements, subset, threads)
    for leaf in leaf_sizes:
        tree, t_tree = timed(B.build_tree, elements, leaf_size=leaf)
        occ, t1 = timed(B.occlusion_passes, elements, tree, passes=1, threads=threads)
        rmse, _, worst = errors(occ[0][subset], exact)
        print(f"| {leaf} | {tree.n_nodes} | {t_tree:.2f} | {t1:.2f} | {rmse:.4f} | {worst:.4f} |")


def section_scaling(configs, threads):
    print(
        f"\n## 3. Scaling at the defaults (theta = {B.DEFAULT_THETA:g}, "
        f"leaf {B.DEFAULT_LEAF_SIZE})\n"
    )
    print(
        "| n | build s | pass 1 s | us per vertex per thread | ratio to previous | n log n ratio |"
    )
    print("|---|---|---|---|---|---|")
    prev = None
    for cells, sub, k in configs:
        surface = spheres_on_ground(cells, sub, k)
        n = surface.n_vertices
        elements, t_el = timed(B.build_elements, surface)
        tree, t_tree = timed(B.build_tree, elements)
        _, t1 = timed(B.occlusion_passes, elements, tree, passes=1, threads=threads)
        ratio = "" if prev is None else f"{t1 / prev[1]:.2f}"
        nlogn = "" if prev is None else f"{n * np.log(n) / (prev[0] * np.log(prev[0])):.2f}"
        print(
            f"| {n} | {t_el + t_tree:.2f} | {t1:.2f} | {1e6 * t1 * threads / n:.1f} "
            f"| {ratio} | {nlogn} |"
        )
        prev = (n, t1)


def section_reference(threads):
    try:
        from aobake.raytrace import embree_ao
    except Exception as exc:  # noqa: BLE001 - optional section
        print(f"\n## 4. skipped: Embree reference unavailable ({exc})")
        return
    import naive_bunnell as nb

    scenes = {
        "sphere on plane": nb.sphere_on_plane(subdivisions=3, cells=40),
        "touching spheres": nb.touching_spheres(subdivisions=3),
        "facing plates": nb.facing_plates(cells=24, gap=0.5),
        "voxel sponge": nb.voxel_sponge(cells=4),
    }
    print("\n## 4. Against the Embree reference (1024 rays): RMSE / bias of ao\n")
    variants = ["K=1", "K=2", "K=3", "K=4", "bunnell K=2", "hoberock K=2", "hoberock K=3"]
    thetas = [2.0, 4.0, 8.0]
    header = variants + [f"tree K=1 theta {t:g}" for t in thetas]
    print("| scene | n | " + " | ".join(header) + " |")
    print("|---|---|" + "---|" * len(header))
    for name, s in scenes.items():
        ref = embree_ao(s, n_rays=1024, seed=0, threads=threads).ao
        ok = s.normals.any(axis=1)
        elements = B.build_elements(s)
        occ = B.occlusion_passes(elements, None, passes=4, threads=threads)
        results = [1.0 - occ[k] for k in range(4)]
        results.append(B.combine_passes(occ[:2], "bunnell"))
        results.append(B.combine_passes(occ[:2], "hoberock"))
        results.append(B.combine_passes(occ[:3], "hoberock"))
        tree = B.build_tree(elements)
        for theta in thetas:
            results.append(
                1.0 - B.occlusion_passes(elements, tree, passes=1, theta=theta, threads=threads)[0]
            )
        cells = []
        for ao in results:
            err = ao[ok] - ref[ok]
            cells.append(f"{np.sqrt(np.mean(err**2)):.3f} / {err.mean():+.3f}")
        print(f"| {name} | {s.n_vertices} | " + " | ".join(cells) + " |")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller meshes (~25k and ~100k)")
    parser.add_argument("--threads", type=int, default=None, help="numba threads (default: all)")
    parser.add_argument("--sections", default="1234", help="which sections to run, e.g. 13")
    parser.add_argument(
        "--check", type=int, default=1000, help="receivers checked against the exact sum"
    )
    args = parser.parse_args()
    import numba

    threads = args.threads or numba.get_num_threads()
    warm_up(threads)
    big = [(230, 5, 4), (600, 7, 2)] if not args.quick else [(110, 4, 4), (230, 5, 4)]
    if "1" in args.sections:
        section_hierarchy(
            [spheres_on_ground(*c) for c in big], [2.0, 4.0, 8.0, 16.0], threads, args.check
        )
    if "2" in args.sections:
        section_leaf(spheres_on_ground(*big[0]), [1, 2, 4, 8, 16], threads, args.check)
    if "3" in args.sections:
        configs = [(110, 4, 4), (230, 5, 4), (460, 6, 4)]
        section_scaling(configs[:2] if args.quick else configs, threads)
    if "4" in args.sections:
        section_reference(threads)


if __name__ == "__main__":
    main()
