"""Benchmark of the disk method (aobake.methods.bunnell).

Prints Markdown tables measured in one run (not a test; the only assertion checks that
the split timing of one pass reproduces ``occlusion_passes``):

1. accuracy: for the bundled meshes (data/*.ply), four hard procedural scenes and the
   ~700k-vertex scene of bench/common.py: RMSE / p99 / bias of ``ao`` against Embree
   with 1024 rays, and time, for the published method (disks, front faces), each
   fix on top of it, passes 1-4 and their combinations, a few theta and near-field
   sizes, and Embree at 16 / 64 / 256 rays on the same mesh;
2. speed on the ~700k scene: build, the per-bake setup of the passes and the time per
   pass (wall and CPU; a pass is what every further pass costs again) for theta / near
   / leaf size, against the exact sum on a random subset of receivers;
3. scaling: setup and time per pass for n, 4n and 16n vertices (goal about n log n);
4. the contenders on the big scene timed round-robin (best of 3 rounds), so that load from
   other processes hits all of them alike, with their error against the reference;
5. a second ~700k-vertex scene (the bunny, loop-subdivided, on a floor): the same
   contenders, round-robin;
6. vertex order: one pass on both big scenes, as generated and with the vertices
   shuffled;
7. receiver buckets split at gaps (``Scheme.bucket_spread``): one pass on both big
   scenes with every leaf whole and at spreads 32 and 8, round-robin, with its RMSE.

References are cached in bench/results/ (Embree 1024 rays on 700k vertices takes minutes).

Usage: ``python bench/bench_bunnell.py [--quick] [--threads N] [--sections 123456]``.
Timings are wall-clock seconds (best of ``--repeats``) with CPU seconds beside them:
CPU / wall shows how many cores the run really had on a shared machine.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from aobake.constants import MEASURE_CODES
from aobake.kernels import bunnell as K
from aobake.kernels import structures as S_
from aobake.methods import bunnell as B
from aobake.methods.bunnell import BunnellOptions
from aobake.methods.bunnell import passes as P
from aobake.methods.bunnell import tree as H
from aobake.methods.embree import embree_ao
from aobake.progress import NullProgress
from aobake.testing import scenes as S

import common

REF_RAYS = 1024
# The opening parameter of the plain-sum rows (no per-direction saturation).
PLAIN_THETA = 4.0
DEFAULTS = BunnellOptions()


def reference(name: str, surface) -> np.ndarray:
    """Embree, 1024 rays, seed 0, cached by name and vertex count."""
    path = common.RESULTS_DIR / f"bunnell_ref_{name}_{surface.n_vertices}_{REF_RAYS}.npy"
    if path.exists():
        return np.load(path)
    ao = embree_ao(surface, n_rays=REF_RAYS, seed=0).ao
    common.RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    np.save(path, ao)
    return ao


def scenes(quick: bool):
    out = {
        "sphere on plane": S.sphere_on_plane(subdivisions=3, cells=40),
        "touching spheres": S.touching_spheres(subdivisions=3),
        "facing plates": S.facing_plates(cells=24, gap=0.5),
        "voxel sponge": S.voxel_sponge(cells=4),
    }
    for s in common.data_scenes():
        out[s.name + ".ply"] = s.surface
    big, desc = common.spheres_on_ground(100_000 if quick else 700_000)
    out[f"spheres on ground ({big.n_vertices // 1000}k)"] = big
    return out, desc


def scores(ao, ref, surface):
    ok = surface.normals.any(axis=1)
    e = ao[ok] - ref[ok]
    return np.sqrt(np.mean(e**2)), np.quantile(np.abs(e), 0.99), e.mean()


def run(fn, repeats):
    """(result, best wall seconds, CPU seconds of that run)."""
    best = None
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        out = fn()
        t, c = time.perf_counter() - t0, time.process_time() - c0
        if best is None or t < best[1]:
            best = (out, t, c)
    return best


def one_pass(elements, tree, repeats, **kw):
    """One pass of ``occlusion_passes(elements, tree, **kw)`` split in two: the per-bake
    setup (``bunnell._Pass``: the cells in tree order, the packed nodes, the bucket
    bounds; paid once however many passes) and the pass itself (``_Pass.sums``, what
    every further pass costs again). Returns (occlusion, setup s, pass s, pass CPU s),
    best of ``repeats`` each; the occlusion is checked against occlusion_passes'."""
    theta = kw.get("theta", DEFAULTS.theta)
    near = kw.get("near", DEFAULTS.near)
    directional = kw.get("directional", True)
    n = elements.n_vertices

    def setup():
        return P._Pass(elements, tree, theta, near, MEASURE_CODES["cosine"], np.inf,
                       directional=directional)

    job, t_setup, _ = run(setup, repeats)
    sums, t_pass, c_pass = run(
        lambda: job.sums(np.ones((n, K.N_LEVELS)), NullProgress(), np.ones(n))[0], repeats
    )
    occ = np.clip(B.combine_sides(sums[:, :, -1]), 0.0, 1.0)
    whole = B.occlusion_passes(elements, tree, BunnellOptions(theta=theta, near=near, directional=directional))[0]
    assert np.array_equal(occ, whole), "one_pass drifted from occlusion_passes"
    return occ, t_setup, t_pass, c_pass


def published_opening(**kw):
    """bunnell_ao with the published opening criterion (``OPEN_COHERENCE = 0``: clusters
    whose normals disagree open no sooner than flat ones), for comparison."""

    def bake(surface):
        saved = H.OPEN_COHERENCE
        H.OPEN_COHERENCE = 0.0
        try:
            return B.variant_ao(surface, **kw)
        finally:
            H.OPEN_COHERENCE = saved

    return bake


def variants(n_vertices: int):
    """(label, callable(surface) -> ao, passes) of every row of the accuracy table."""
    big = n_vertices > 50_000
    plain = dict(directional=False, theta=PLAIN_THETA)  # the sums before saturation
    rows = [
        ("published: disks, front faces (near 0), plain sums", dict(near=0.0, sides="front", **plain)),
        ("+ cells (near 4), front faces", dict(sides="front", **plain)),
        ("+ max(front, back) (plain sums, theta 4)", dict(plain)),
        ("default: + per-direction saturation, theta 2", dict()),
    ]
    if not big:
        rows.append(("default, exact sum (no tree)", dict(exact=True)))
    rows += [
        ("saturation, theta 1.5", dict(theta=1.5)),
        ("saturation, theta 3", dict(theta=3.0)),
        ("saturation, theta 4", dict(theta=4.0)),
        ("saturation, theta 8", dict(theta=8.0)),
        ("saturation, disks only (near 0)", dict(near=0.0)),
        ("saturation, near 1", dict(near=1.0)),
        ("saturation, near 16", dict(near=16.0)),
        ("saturation, theta 4, near 16", dict(theta=4.0, near=16.0)),
        ("passes 2", dict(passes=2)),
        ("passes 2, theta 4", dict(passes=2, theta=4.0)),
        ("passes 2 without the fill rule (pass_fill off; the previous passes 2)", dict(passes=2, pass_fill=False)),
        ("passes 2, damping 0.25", dict(passes=2, damping=0.25)),
        ("passes 3", dict(passes=3)),
        ("plain: passes 2", dict(passes=2, **plain)),
        ("plain: passes 2, every vertex (share_passes off)", dict(passes=2, share_passes=False, **plain)),
        ("plain: passes 2, ungated (gate 0)", dict(passes=2, gate=0.0, **plain)),
        ("plain: passes 3", dict(passes=3, **plain)),
        ("plain: passes 4", dict(passes=4, **plain)),
        ("plain: passes 2, pass_reach 0.25", dict(passes=2, pass_reach=0.25, **plain)),
        ("plain: passes 2, pass_reach 1", dict(passes=2, pass_reach=1.0, **plain)),
        ("plain: passes 2, damping 0.5", dict(passes=2, damping=0.5, **plain)),
        ("plain: passes 2, bunnell blend", dict(passes=2, combine="bunnell", **plain)),
        ("plain: passes 2, Bunnell's weights (pass_reach inf, gate 0)", dict(passes=2, pass_reach=np.inf, gate=0.0, **plain)),
        ("plain: passes 3, Bunnell's weights", dict(passes=3, pass_reach=np.inf, gate=0.0, **plain)),
        ("plain: passes 2, Bunnell's weights, bunnell blend", dict(passes=2, pass_reach=np.inf, gate=0.0, combine="bunnell", **plain)),
        ("plain: passes 2, Bunnell's weights, hoberock blend", dict(passes=2, pass_reach=np.inf, gate=0.0, combine="hoberock", **plain)),
        ("plain: passes 3, Bunnell's weights, hoberock blend", dict(passes=3, pass_reach=np.inf, gate=0.0, combine="hoberock", **plain)),
        ("published, passes 2, bunnell blend", dict(near=0.0, sides="front", passes=2, pass_reach=np.inf, gate=0.0, combine="bunnell", **plain)),
    ]
    out = [(label, (lambda s, kw=kw: B.variant_ao(s, **kw)), kw.get("passes", 1)) for label, kw in rows]
    out.insert(4, ("default, published opening (OPEN_COHERENCE 0)", published_opening(), 1))
    out.insert(5, ("passes 2, published opening", published_opening(passes=2), 2))
    out += [(f"embree {n} rays", (lambda s, n=n: embree_ao(s, n_rays=n, seed=1).ao), 1) for n in (16, 64, 256)]
    return out


def section_accuracy(all_scenes, repeats):
    print(f"\n## 1. Accuracy against Embree ({REF_RAYS} rays): RMSE / p99 / bias of ao, and time\n")
    names = list(all_scenes)
    results = {}
    for name, s in all_scenes.items():
        ref = reference(name.split(" (")[0].replace(" ", "_").replace(".", "_"), s)
        rows = []
        for label, fn, _ in variants(s.n_vertices):
            reps = repeats if s.n_vertices > 50_000 else max(repeats, 3)
            ao, wall, cpu = run(lambda fn=fn, s=s: fn(s), reps)
            rmse, p99, bias = scores(ao, ref, s)
            rows.append((label, rmse, p99, bias, wall, cpu))
            print(f"  {name}: {label}: {rmse:.4f} {wall:.2f}s", file=sys.stderr, flush=True)
        results[name] = rows
    labels = [r[0] for r in next(iter(results.values()))]
    big = names[-1]
    print("RMSE (p99) per scene; time in seconds on the big scene (wall / CPU):\n")
    header = ["variant"] + [f"{n} [{all_scenes[n].n_vertices}]" for n in names] + ["big: s (CPU s)"]
    table = []
    for label in labels:
        row = [label]
        for n in names:
            hit = [r for r in results[n] if r[0] == label]
            row.append(f"{hit[0][1]:.4f} ({hit[0][2]:.3f})" if hit else "-")
        hit = [r for r in results[big] if r[0] == label]
        row.append(f"{hit[0][4]:.2f} ({hit[0][5]:.2f})" if hit else "-")
        table.append(row)
    print(common.markdown_table(header, table, "l" + "r" * (len(header) - 1)))
    print("\nBias (mean of ao - reference; negative = too dark):\n")
    table = [[label] + [
        next((f"{r[3]:+.3f}" for r in results[n] if r[0] == label), "-") for n in names
    ] for label in labels]
    print(common.markdown_table(["variant"] + names, table, "l" + "r" * len(names)))
    return results


def exact_subset(elements, subset, near, directional=True):
    """Exact pass-1 occlusion (max rule) at ``subset`` receivers (brute force)."""
    job = P._Pass(elements, None, DEFAULTS.theta, near, K.MEASURE_COSINE, np.inf,
                  directional=directional)
    out = np.zeros((elements.n_vertices, 2, K.N_BINS))
    ones = np.ones(elements.n_vertices)
    disks = S_.Disks(elements.positions, elements.normals, elements.areas,
                     np.ones((elements.n_vertices, K.N_LEVELS)), elements.positions)
    cells = S_.Cells(elements.corner_start, elements.corners, ones)
    first = np.zeros((elements.n_vertices, 4))
    K.brute_force_pass(disks, cells, elements.emitter_index, job.receivers, subset, job.options,
                       out, first, job.no_fill)
    return np.clip(out[:, :, -1].max(axis=1)[subset], 0.0, 1.0)


def section_speed(surface, desc, repeats, n_check):
    import numba

    print(f"\n## 2. Speed on {surface.n_vertices} vertices ({desc}), {numba.get_num_threads()} threads\n")
    (elements, t_el, c_el) = run(lambda: B.build_elements(surface), repeats)
    tree, t_build, _ = run(lambda: B.build_tree(elements), repeats)
    _, t_refit, _ = run(lambda: B.refit_tree(tree, elements.positions, elements.areas), repeats)
    print(f"build_elements: {t_el:.2f} s (CPU {c_el:.2f} s); build_tree {t_build:.2f} s, "
          f"refit_tree (animation: same mesh, new positions) {t_refit:.2f} s\n")
    subset = np.sort(np.random.default_rng(0).choice(surface.n_vertices, n_check, replace=False))
    exact = {(nu, d): exact_subset(elements, subset, nu, d) for nu in (0.0, 4.0) for d in (True, False)}
    rows = []
    for leaf in (16, 32, 64):
        tree, t_tree, c_tree = run(lambda leaf=leaf: B.build_tree(elements, leaf_size=leaf), repeats)
        for directional in (True, False):
            for theta in (2.0, 4.0, 8.0):
                for nu in (0.0, 4.0):
                    if leaf != P.DEFAULT_LEAF_SIZE and (theta != DEFAULTS.theta or not directional):
                        continue
                    occ, t0, t1, c1 = one_pass(elements, tree, repeats, theta=theta, near=nu,
                                               directional=directional)
                    e = occ[subset] - exact[nu, directional]
                    rows.append([leaf, f"{t_tree:.2f}", "yes" if directional else "no", theta, nu,
                                 f"{t0:.2f}", f"{t1:.2f}", f"{c1:.2f}",
                                 f"{np.sqrt(np.mean(e**2)):.4f}",
                                 f"{np.quantile(np.abs(e), 0.99):.4f}"])
                    print(f"  leaf {leaf} dir {directional} theta {theta} near {nu}: {t1:.2f}s",
                          file=sys.stderr, flush=True)
    print(common.markdown_table(
        ["leaf", "tree s", "saturation", "theta", "near", "setup s", "pass s", "pass CPU s",
         f"RMSE vs exact ({n_check})", "p99"],
        [[str(c) for c in r] for r in rows],
    ))
    for passes in (1, 2):
        _, t_all, c_all = run(lambda passes=passes: B.variant_ao(surface, passes=passes), repeats)
        print(f"\nbunnell_ao, passes={passes}, everything included: {t_all:.2f} s (CPU {c_all:.2f} s)")


def section_scaling(threads, repeats):
    print(f"\n## 3. Scaling at the defaults (theta {DEFAULTS.theta:g}, near {DEFAULTS.near:g}, "
          f"leaf {P.DEFAULT_LEAF_SIZE})\n")
    rows = []
    prev = None
    for n_target in (44_000, 175_000, 700_000):
        s, _ = common.spheres_on_ground(n_target)
        n = s.n_vertices
        elements = B.build_elements(s)
        tree, t_tree, _ = run(lambda elements=elements: B.build_tree(elements), repeats)
        _, t0, t1, c1 = one_pass(elements, tree, repeats)
        ratio = "" if prev is None else f"{t1 / prev[1]:.2f}"
        cratio = "" if prev is None else f"{c1 / prev[2]:.2f}"
        nlogn = "" if prev is None else f"{n * np.log(n) / (prev[0] * np.log(prev[0])):.2f}"
        rows.append([str(n), f"{t_tree:.2f}", f"{t0:.2f}", f"{t1:.2f}", f"{c1:.2f}", f"{1e6 * c1 / n:.2f}",
                     ratio, cratio, nlogn])
        prev = (n, t1, c1)
    print(common.markdown_table(
        ["n", "tree s", "setup s", "pass s", "pass CPU s", "CPU us / vertex", "time ratio", "CPU ratio",
         "n log n ratio"],
        rows,
    ))


def contenders(surface):
    """The big-scene round-robin: the defaults, the plain sums, Embree at 16 and 64 rays."""
    return {
        "bunnell published (near 0, front faces, plain sums)": lambda: B.variant_ao(
            surface, near=0.0, sides="front", directional=False, theta=PLAIN_THETA),
        "bunnell --no-directional --theta 4 (plain sums)": lambda: B.variant_ao(
            surface, directional=False, theta=PLAIN_THETA),
        "bunnell --no-directional --theta 4 --passes 2": lambda: B.variant_ao(
            surface, directional=False, theta=PLAIN_THETA, passes=2),
        "bunnell default, published opening (OPEN_COHERENCE 0)": lambda: published_opening()(surface),
        "bunnell default (saturation, theta 2)": lambda: B.variant_ao(surface),
        "bunnell --theta 1.5": lambda: B.variant_ao(surface, theta=1.5),
        "bunnell --theta 4": lambda: B.variant_ao(surface, theta=4.0),
        "embree 16 rays": lambda: embree_ao(surface, n_rays=16, seed=1).ao,
        "embree 64 rays": lambda: embree_ao(surface, n_rays=64, seed=1).ao,
    }


def round_robin(surface, ref):
    """Time the contenders round-robin (best of 3 rounds) and score them against ref."""
    res = common.interleaved(contenders(surface), repeats=3)
    rows = []
    for k, v in res.items():
        rmse, p99, bias = scores(v.result, ref, surface)
        rows.append([k, f"{rmse:.4f}", f"{p99:.3f}", f"{bias:+.4f}", f"{v.seconds:.2f}",
                     f"{v.cpu:.2f}", f"{v.cores:.2f}"])
    print(common.markdown_table(["method", "RMSE", "p99", "bias", "wall s", "CPU s", "cores busy"], rows))


def section_timing(surface):
    print(f"\n## 4. Round-robin on {surface.n_vertices} vertices (best of 3 rounds; RMSE / p99 / "
          f"bias against Embree {REF_RAYS} rays)\n")
    round_robin(surface, reference("spheres_on_ground", surface))


def section_bunny(n_vertices):
    """The second big scene: a smooth scanned object on a floor (bench/common.py)."""
    surface, desc = common.bunny_on_ground(n_vertices)
    print(f"\n## 5. Second big scene: {desc}, {surface.n_vertices} vertices "
          f"(round-robin, best of 3; RMSE / p99 / bias against Embree {REF_RAYS} rays)\n")
    round_robin(surface, reference("bunny_on_ground", surface))


def section_vertex_order(n_vertices, repeats):
    """Per-pass time on both big scenes in their generated vertex order and shuffled
    (scanned and subdivided meshes come in any order): the cells are read in tree order,
    so the order should cost little."""
    from aobake.mesh import surface_from_arrays

    print(f"\n## 6. Vertex order: one pass at the defaults, generated vs shuffled order "
          f"(best of {repeats})\n")
    rows = []
    for name, make in (("spheres", common.spheres_on_ground), ("bunny", common.bunny_on_ground)):
        s, _ = make(n_vertices)
        shuffle = np.random.default_rng(0).permutation(s.n_vertices)
        back = np.argsort(shuffle)
        shuffled = surface_from_arrays(s.positions[shuffle], back[s.faces], s.normals[shuffle])
        row = [f"{name} ({s.n_vertices})"]
        for surface in (s, shuffled):
            elements = B.build_elements(surface)
            tree = B.build_tree(elements)
            _, t0, t1, c1 = one_pass(elements, tree, repeats)
            row.append(f"{t0:.2f} + {t1:.2f} ({c1:.2f})")
        rows.append(row)
    print(common.markdown_table(
        ["scene", "generated order: setup + pass s (pass CPU)", "shuffled: setup + pass s (pass CPU)"], rows
    ))


def section_split(n_vertices, repeats):
    """One pass with the receiver buckets split at gaps or not (docs/bunnell.md, "Receiver
    buckets split at gaps"): setup + pass times round-robin, and the RMSE of the whole
    bake at each spread."""
    print(f"\n## 7. Receiver buckets split at gaps: one pass at the defaults, round-robin "
          f"(best of {repeats}; RMSE against Embree {REF_RAYS} rays)\n")
    rows = []
    for key, make in (("spheres_on_ground", common.spheres_on_ground),
                      ("bunny_on_ground", common.bunny_on_ground)):
        s, _ = make(n_vertices)
        ref = reference(key, s)
        elements = B.build_elements(s)
        tree = B.build_tree(elements)
        ones = np.ones(elements.n_vertices)
        jobs = {spread: P._Pass(elements, tree, DEFAULTS.theta, DEFAULTS.near,
                                MEASURE_CODES["cosine"], np.inf, spread=spread)
                for spread in (np.inf, 32.0, 8.0)}
        times = common.interleaved(
            {k: lambda job=job, w=ones: job.sums(w, NullProgress(), w) for k, job in jobs.items()},
            repeats,
        )
        for spread, job in jobs.items():
            rmse, _, bias = scores(B.variant_ao(s, bucket_spread=spread), ref, s)
            t = times[spread]
            rows.append([f"{key} ({elements.n_vertices})", f"{spread:g}",
                         str(job.bucket_start.shape[0] - 1), f"{t.seconds:.2f}", f"{t.cpu:.2f}",
                         f"{rmse:.5f}", f"{bias:+.5f}"])
    print(common.markdown_table(
        ["scene", "bucket_spread", "buckets", "pass s", "pass CPU s", "RMSE", "bias"], rows
    ))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="100k instead of 700k vertices")
    parser.add_argument("--threads", type=int, default=None, help="numba threads (default: all)")
    parser.add_argument("--sections", default="1234567", help="which sections to run, e.g. 13")
    parser.add_argument("--repeats", type=int, default=2, help="best of this many runs")
    parser.add_argument("--check", type=int, default=2000, help="receivers checked against the exact sum")
    args = parser.parse_args()
    import numba

    if args.threads:
        numba.set_num_threads(args.threads)
    print("# bench_bunnell\n")
    for label, value in common.machine_facts():
        print(f"- {label}: {value}")
    B.variant_ao(common.spheres_on_ground(25_000)[0])  # compile
    all_scenes, desc = scenes(args.quick)
    if "1" in args.sections:
        section_accuracy(all_scenes, args.repeats)
    if "2" in args.sections:
        section_speed(list(all_scenes.values())[-1], desc, args.repeats, args.check)
    if "3" in args.sections and not args.quick:
        section_scaling(numba.get_num_threads(), args.repeats)
    if "4" in args.sections:
        section_timing(list(all_scenes.values())[-1])
    if "5" in args.sections:
        section_bunny(100_000 if args.quick else 700_000)
    if "6" in args.sections:
        section_vertex_order(100_000 if args.quick else 700_000, args.repeats)
    if "7" in args.sections:
        section_split(100_000 if args.quick else 700_000, args.repeats)


if __name__ == "__main__":
    main()
