"""Benchmark of ``aobake batch``: a library of small meshes against ``make -j2 batch``, an
up-to-date rerun, and one large mesh baked as 2 vertex ranges against one unsplit bake.

1. Library: ``--meshes`` (200) small scenes (:func:`aobake.testing.scenes.spheres_in_block_arrays`
   at 600..2000 vertices, each turned by its own random rotation, so every file differs),
   binary PLY. Baked to PLY + USDA with ``--rays`` (256) by
   ``aobake batch LIB -o OUT --workers 2`` and by ``make -j2 batch IN=LIB OUT=OUT2`` (one
   ``aobake bake`` process per mesh), wall times of one run each; both sets of outputs
   must be byte-identical. Per-input overhead = (wall x 2 - the bakes' compute seconds
   from the manifest) / meshes: what each way spends besides tracing. Then the batch is
   run again (everything up to date): its wall time.
2. Large mesh: ``--big`` (4 M) vertices (4 icospheres on a floor grid), ``--big-rays`` (64)
   rays, PLY out. ``aobake bake`` (all cores) against ``aobake batch --split 2 --workers 2``
   (each worker 1 thread, one range each, its own scene). The goal's bound is
   1.1 x (unsplit wall + one more load and scene build: ``load_mesh`` + ``Tracer`` +
   contact-safe origins, timed in this process); the outputs must be identical.

Usage: ``python bench/bench_batch.py [--quick]`` (``make bench-batch``). Every number is a
wall time of this run on this machine (shared: compare rows of one run).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from aobake.io import load_mesh, write_ply
from aobake.testing import scenes

ROOT = Path(__file__).resolve().parent.parent
PY = sys.executable


def env() -> dict:
    e = dict(os.environ)
    e["PYTHONPATH"] = str(ROOT) + os.pathsep + e.get("PYTHONPATH", "")
    return e


def run(cmd: list[str], **kw) -> float:
    """Wall seconds of a command (it must succeed)."""
    t0 = time.perf_counter()
    done = subprocess.run(cmd, env=env(), capture_output=True, text=True, **kw)
    seconds = time.perf_counter() - t0
    if done.returncode != 0:
        sys.exit(f"failed ({done.returncode}): {' '.join(cmd)}\n{done.stderr[-2000:]}")
    return seconds


def rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def write_mesh(path: Path, positions, faces) -> None:
    write_ply(path, positions, faces, np.ones(len(positions)))  # ao = 1: ignored as input


def make_library(directory: Path, count: int) -> int:
    rng = np.random.default_rng(17)
    total = 0
    for k in range(count):
        positions, faces, _ = scenes.spheres_in_block_arrays(int(rng.integers(600, 2000)))
        write_mesh(directory / f"m{k:03d}.ply", positions @ rotation(rng).T, faces)
        total += len(positions)
    return total


def same_files(a: Path, b: Path, names) -> bool:
    return all((a / n).read_bytes() == (b / n).read_bytes() for n in names)


def library_section(work: Path, count: int, rays: int) -> dict:
    lib = work / "lib"
    lib.mkdir()
    vertices = make_library(lib, count)
    aobake = [PY, "-m", "aobake"]
    out_batch, out_make = work / "out_batch", work / "out_make"
    flags = ["--rays", str(rays), "--quiet"]
    # warm the numba cache once, so neither contender pays the first compilation
    run([*aobake, "bake", str(lib / "m000.ply"), "-o", str(work / "warm.ply"), *flags])
    t_batch = run([*aobake, "batch", str(lib), "-o", str(out_batch), "--workers", "2", *flags])
    venv = Path(PY).parent.parent
    t_make = run(
        ["make", "-C", str(ROOT), "-j2", "--no-print-directory", "batch", f"IN={lib}", f"OUT={out_make}",
         f"VENV={venv}", f"BAKE_FLAGS={' '.join(flags)}"]
    )  # fmt: skip
    t_rerun = run([*aobake, "batch", str(lib), "-o", str(out_batch), "--workers", "2", *flags])
    manifest = json.loads((out_batch / "manifest.json").read_text())
    compute = sum(r["seconds"] for r in manifest["inputs"])
    names = [f"m{k:03d}.{ext}" for k in range(count) for ext in ("ply", "usda")]
    return {
        "meshes": count,
        "vertices": vertices,
        "rays": rays,
        "batch": t_batch,
        "make": t_make,
        "rerun": t_rerun,
        "compute": compute,
        "identical": same_files(out_batch, out_make, names),
    }


def scene_build_seconds(path: Path) -> float:
    """Load + Embree scene + contact-safe origins: what each --split task repeats."""
    from aobake.contacts import contact_origins, ray_offsets
    from aobake.kernels import topology
    from aobake.tracing import Tracer

    t0 = time.perf_counter()
    surface = load_mesh(path)
    tracer = Tracer(surface.positions, surface.faces)
    edges = topology.longest_edges(surface.positions, surface.faces)
    contact_origins(surface, tracer, ray_offsets(surface, tracer.magnitude, None, edges), edges)
    return time.perf_counter() - t0


def split_section(work: Path, n_vertices: int, rays: int) -> dict:
    positions, faces, desc = scenes.spheres_in_block_arrays(n_vertices)
    big = work / "big.ply"
    write_mesh(big, positions, faces)
    del positions, faces
    aobake = [PY, "-m", "aobake"]
    flags = ["--rays", str(rays), "--quiet"]
    scene_build_seconds(big)  # warm caches (numba, file pages) once
    build = scene_build_seconds(big)
    t_unsplit = run([*aobake, "bake", str(big), "-o", str(work / "unsplit.ply"), *flags])
    out = work / "split"
    t_split = run([*aobake, "batch", str(big), "-o", str(out), "--to", "ply", "--split", "2", "--workers", "2", *flags])
    identical = (work / "unsplit.ply").read_bytes() == (out / "big.ply").read_bytes()
    n = len(load_mesh(big).positions)
    return {
        "vertices": n,
        "desc": desc,
        "rays": rays,
        "unsplit": t_unsplit,
        "split": t_split,
        "build": build,
        "identical": identical,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--meshes", type=int, default=200, help="small meshes (0: skip that section)")
    parser.add_argument("--rays", type=int, default=256)
    parser.add_argument("--big", type=int, default=4_000_000)
    parser.add_argument("--big-rays", type=int, default=64)
    parser.add_argument("--quick", action="store_true", help="20 meshes, a 400k-vertex mesh")
    args = parser.parse_args()
    if args.quick:
        args.meshes, args.big = 20, 400_000
    print(f"# bench_batch: {platform.node()}, {os.cpu_count()} cores, python {platform.python_version()}\n")
    work = Path(tempfile.mkdtemp(prefix="aobake-bench-batch-"))
    try:
        if args.meshes > 0:  # --meshes 0: the --split section alone
            lib = library_section(work, args.meshes, args.rays)
            m = lib["meshes"]
            print(f"## {m} small meshes ({lib['vertices'] / m:.0f} vertices on average), {lib['rays']} rays, PLY + USDA\n")
            print("| run | wall s | meshes/s | overhead per mesh, s |")
            print("|---|---:|---:|---:|")
            for name, t in (("aobake batch --workers 2", lib["batch"]), ("make -j2 batch", lib["make"])):
                print(f"| {name} | {t:.2f} | {m / t:.1f} | {(2 * t - lib['compute']) / m:.3f} |")
            print(f"| aobake batch, rerun (all up to date) | {lib['rerun']:.2f} | | |")
            print(
                f"\nbatch / make wall time: {lib['batch'] / lib['make']:.3f}; the bakes' compute time "
                f"{lib['compute']:.2f} s in all; outputs byte-identical: {lib['identical']}\n"
            )
        big = split_section(work, args.big, args.big_rays)
        bound = 1.1 * (big["unsplit"] + big["build"])
        print(f"## one mesh of {big['vertices']} vertices ({big['desc']}), {big['rays']} rays, PLY\n")
        print("| run | wall s |")
        print("|---|---:|")
        print(f"| aobake bake (all cores) | {big['unsplit']:.2f} |")
        print(f"| aobake batch --split 2 --workers 2 | {big['split']:.2f} |")
        print(f"| one load + scene build (in process) | {big['build']:.2f} |")
        print(
            f"\nsplit / (unsplit + one more build): {big['split'] / (big['unsplit'] + big['build']):.3f} "
            f"(goal <= 1.1: {big['split'] <= bound}); output identical: {big['identical']}"
        )
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
