"""Disk-to-disk light transfer through the cluster tree (issue 16) against the brute-force
sum: time per call and error at several theta, the prepare / re-light split, on ~100k
vertices.

    PYTHONPATH=. python bench/bench_transfer.py [--vertices 100000] [--scene spheres|bunny]
        [--repeats 3] [--threads 2] [--relight-only]

The scene is bench/common.py's four balls on a floor (``--scene bunny``: the bunny on a
floor), every vertex sending the radiance
of a diffuse surface (albedo (0.8, 0.5, 0.3)) under a distant light, unshadowed:
``max(n.l, 0) albedo``. Re-lighting moves that light: each timed call gathers a new
radiance through the same prepared scene (the radiance itself is the caller's; the goal
of issue 16 is <= 0.2 s per call on 100k vertices). Prints wall and CPU seconds (all
threads) measured in one run, and ratios against the brute-force sum; docs/bunnell-light.md
records runs.
"""

from __future__ import annotations

import argparse

import numpy as np

from aobake.methods.bunnell.elements import build_elements
from aobake.methods.bunnell.transfer import (
    DEFAULT_TRANSFER_NEAR,
    DEFAULT_TRANSFER_THETA,
    prepare_transfer,
    tree_transfer,
    unshadowed_irradiance,
)

from common import (
    bunny_on_ground,
    fmt_s,
    interleaved,
    machine_facts,
    print_table,
    spheres_on_ground,
    timed,
)

ALBEDO = np.array([0.8, 0.5, 0.3])


def lit(elements, azimuth):
    """Radiance under a distant light at elevation 53 degrees and the given azimuth."""
    d = np.array([0.6 * np.cos(azimuth), 0.6 * np.sin(azimuth), 0.8])
    return np.maximum(elements.normals @ d, 0.0)[:, None] * ALBEDO


def errors(got, want):
    """Relative RMSE and the largest error over the largest value."""
    rel = float(np.sqrt(np.mean((got - want) ** 2)) / np.sqrt(np.mean(want**2)))
    return rel, float(np.max(np.abs(got - want)) / want.max())


def relight(el, radiance, args):
    """Time per re-lighting call at the defaults, all threads and one thread, interleaved."""
    import numba

    prep = timed(lambda: prepare_transfer(el))
    scene = prep.result
    calls = iter(range(10**9))
    threads = args.threads or numba.config.NUMBA_NUM_THREADS

    def call(n):
        numba.set_num_threads(n)
        return scene.gather(radiance[next(calls) % len(radiance)])

    t = interleaved({"all": lambda: call(threads), "one": lambda: call(1)}, args.repeats)
    numba.set_num_threads(threads)
    print(f"\nprepare {fmt_s(prep.seconds)} s; per call: {fmt_s(t['all'].seconds)} s wall ({fmt_s(t['all'].cpu)} s CPU) "
          f"on {threads} threads, {fmt_s(t['one'].seconds)} s wall ({fmt_s(t['one'].cpu)} s CPU) on one; "
          f"goal <= 0.2 s: {'met' if t['all'].seconds <= 0.2 else 'NOT met'}")  # fmt: skip


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vertices", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--thetas", default="1,2,4,8,16")
    parser.add_argument("--scene", choices=("spheres", "bunny"), default="spheres")
    parser.add_argument("--relight-only", action="store_true", help="only time re-lighting calls at the defaults")
    args = parser.parse_args()
    import numba

    if args.threads:
        numba.set_num_threads(args.threads)
    for k, v in machine_facts():
        print(f"{k}: {v}")
    print(f"numba threads: {numba.get_num_threads()}")
    surface, desc = (spheres_on_ground if args.scene == "spheres" else bunny_on_ground)(args.vertices)
    el = build_elements(surface)
    print(f"scene: {desc}, {el.n_vertices} vertices")
    radiance = [lit(el, a) for a in np.linspace(0.0, 2.0 * np.pi, 6, endpoint=False)]

    # warm the compiled code on a small call, then the brute force once (it is slow)
    small = build_elements(spheres_on_ground(5000, cache=False)[0])
    tree_transfer(small, lit(small, 0.0))
    if args.relight_only:
        relight(el, radiance, args)
        return
    unshadowed_irradiance(small, lit(small, 0.0))
    brute = timed(lambda: unshadowed_irradiance(el, radiance[0]))
    want = brute.result

    thetas = [float(x) for x in args.thetas.split(",")]
    rows = []
    per_call = {}

    def row(theta, near, reference, label):
        prep = timed(lambda: prepare_transfer(el, theta=theta, near=near))
        scene = prep.result
        calls = iter(range(10**9))

        def call():
            return scene.gather(radiance[next(calls) % len(radiance)])

        t = interleaved({"call": call}, args.repeats)["call"]
        first = scene.gather(radiance[0])
        assert np.array_equal(first, tree_transfer(el, radiance[0], theta=theta, near=near))
        rel, peak = errors(first, reference)
        per_call[(theta, near)] = t
        rows.append([
            label, f"{theta:g}", f"{near:g}", f"{rel:.2e}", f"{peak:.2e}", fmt_s(prep.seconds),
            fmt_s(t.seconds), fmt_s(t.cpu), f"{brute.seconds / t.seconds:.0f}x", f"{brute.cpu / t.cpu:.0f}x",
        ])  # fmt: skip

    for theta in sorted(thetas):
        row(theta, 0.0, want, "disks only, vs brute force")
    exact_near = timed(lambda: prepare_transfer(el, theta=np.inf).gather(radiance[0]))
    default = (DEFAULT_TRANSFER_THETA, DEFAULT_TRANSFER_NEAR)
    row(*default, exact_near.result, "**default**, vs theta inf")
    print_table(
        f"tree transfer against the brute-force sum ({fmt_s(brute.seconds)} s wall, {fmt_s(brute.cpu)} s CPU), "
        f"{el.n_vertices} vertices",
        ["rows", "theta", "near", "rel. RMSE", "max err / peak", "prepare (s)", "per call (s, wall)",
         "per call (s, CPU)", "brute / call (wall)", "brute / call (CPU)"],
        rows,
        note="per call: best of the repeats, each with a different light direction through the same "
        "prepared scene; prepare: tree, node geometry, buckets, near-field cells (once per scene, "
        "again after vertices move); the default row's reference is the same near field with every "
        f"cluster opened ({fmt_s(exact_near.seconds)} s wall)",
    )  # fmt: skip
    d = per_call[default]
    # the work of a call, steadier than wall time on a shared machine: CPU seconds on one thread
    numba.set_num_threads(1)
    scene = prepare_transfer(el)
    one = interleaved({"call": lambda: scene.gather(radiance[1])}, args.repeats)["call"]
    numba.set_num_threads(args.threads or numba.config.NUMBA_NUM_THREADS)
    print(f"\none thread, defaults: {fmt_s(one.seconds)} s wall, {fmt_s(one.cpu)} s CPU per call")
    verdict = "met" if d.seconds <= 0.2 else "NOT met"
    print(f"\nre-light at the defaults (theta {default[0]:g}, near {default[1]:g}): {fmt_s(d.seconds)} s per call "
          f"({fmt_s(d.cpu)} s CPU, all threads; goal <= 0.2 s wall: {verdict})")  # fmt: skip


if __name__ == "__main__":
    main()
