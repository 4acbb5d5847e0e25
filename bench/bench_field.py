"""Benchmark of ambient occlusion fields (aobake.methods.fields): accuracy, fit time, size, speed.

The scene: the bundled bunny (``data/bunny.ply``, +Y up) resting on a square ground grid
at its lowest point, 3 bounding radii wide (101 x 101 vertices, normals +Y). The
reference is Embree AO on the ground cast by the bunny alone (4096 Owen-scrambled Sobol
rays per vertex, contact-aware origins; a flat ground does not occlude itself), cached
under ``bench/results/``. For each configuration the table gives:

- fit: wall seconds of :func:`aobake.methods.fields.fit_field` (JIT cache warm);
- bytes: size of the written ``field.npz``;
- RMSE / p99 / max of the field's ao on the ground against the reference, and the RMSE
  on the contact ring (ground vertices within 0.2 bounding radii of the hull);
- eval: receivers per second of :func:`aobake.methods.fields.fields_ao` on 2 M receivers
  (best of 3, all numba threads), measured once per model.

A "cap floor" row evaluates the spherical-cap approximation with exact Omega and Y at
each receiver (cube maps of 128^2 texels): no field can beat it.

Usage: ``python bench/bench_field.py [--quick] [--threads N]``. Timings depend on the
machine's load: compare rows of one run.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from aobake.io import load_mesh
from aobake.mesh import surface_from_arrays
from aobake.methods.embree import embree_ao
from aobake.methods.fields import (
    cap_integral,
    fields_ao,
    fit_field,
    hull_distance,
    raster_occlusion,
    save_field,
)

from common import DATA_DIR, RESULTS_DIR, machine_facts, markdown_table, rmse

REFERENCE_RAYS = 4096
CELLS = 100
#: Bump when the scene or the reference changes, so stale caches are not reused.
SCENE_VERSION = 1


def scene():
    """Bunny surface, ground positions and normals, reference ao, bounding radius."""
    bunny = load_mesh(DATA_DIR / "bunny.ply")
    p = bunny.positions
    lo, hi = p.min(axis=0), p.max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = float(np.linalg.norm(p - centre, axis=1).max())
    t = np.linspace(-1.5 * radius, 1.5 * radius, CELLS + 1)
    x, z = np.meshgrid(t, t, indexing="ij")
    ground = np.c_[x.ravel() + centre[0], np.full(x.size, lo[1]), z.ravel() + centre[2]]
    normals = np.tile([0.0, 1.0, 0.0], (ground.shape[0], 1))
    cache = RESULTS_DIR / f"field_reference_v{SCENE_VERSION}_{CELLS}_{REFERENCE_RAYS}.npz"
    if cache.exists():
        ref = np.load(cache)["ao"]
    else:
        i, j = np.meshgrid(np.arange(CELLS), np.arange(CELLS), indexing="ij")
        a = (i * (CELLS + 1) + j).ravel()
        faces = np.vstack([np.c_[a, a + CELLS + 2, a + CELLS + 1], np.c_[a, a + 1, a + CELLS + 2]])
        both = surface_from_arrays(
            np.vstack([ground, p]), np.vstack([faces, bunny.faces + len(ground)]), np.vstack([normals, bunny.normals])
        )
        ref = embree_ao(both, n_rays=REFERENCE_RAYS, seed=12345).ao[: len(ground)]
        RESULTS_DIR.mkdir(parents=True, exist_ok=True)
        np.savez(cache, ao=ref)
    return bunny, ground, normals, ref, radius


def eval_rate(f, ground, threads, n=2_000_000) -> float:
    """Receivers per second over ``n`` receivers spread over the ground's square, up to
    0.3 bounding radii above it (best of 3)."""
    rng = np.random.default_rng(0)
    lo, hi = ground.min(axis=0), ground.max(axis=0)
    p = rng.uniform(lo, hi, size=(n, 3))
    p[:, 1] = lo[1] + rng.uniform(0.0, 0.3 * f.radius, n)
    normals = np.tile([0.0, 1.0, 0.0], (n, 1))
    fields_ao([f], p[:100], normals[:100], threads=threads)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        fields_ao([f], p, normals, threads=threads)
        best = min(best, time.perf_counter() - t0)
    return n / best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="only the defaults of each sampler")
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()

    bunny, ground, normals, ref, radius = scene()
    x = ground - fit_field(bunny, resolution=1, radial_samples=3, raster_size=4).centre  # warm the JIT caches
    fit_field(bunny, sampler="embree", resolution=1, radial_samples=3, n_rays=4)
    centre = ground[0] - x[0]
    near = (np.linalg.norm(x, axis=1) - hull_distance(bunny.positions, x, centre)) < 0.2 * radius

    configs = [dict(sampler="raster"), dict(sampler="embree")]
    if not args.quick:
        configs = [
            dict(sampler="raster", resolution=8),
            dict(sampler="raster"),
            dict(sampler="raster", resolution=32),
            dict(sampler="raster", model="paper"),
            dict(sampler="raster", model="table", resolution=8),
            dict(sampler="raster", model="table"),
            dict(sampler="raster", prefilter=2),
            dict(sampler="raster", raster_size=64),
            dict(sampler="embree", resolution=8),
            dict(sampler="embree"),
            dict(sampler="embree", resolution=32),
            dict(sampler="embree", model="table"),
        ]
    rows, records, rates = [], [], {}
    for cfg in configs:
        t0 = time.perf_counter()
        f = fit_field(bunny, threads=args.threads, **cfg)
        seconds = time.perf_counter() - t0
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "field.npz"
            save_field(f, path)
            size = path.stat().st_size
        ao = fields_ao([f], ground, normals, threads=args.threads).ao
        err = np.abs(ao - ref)
        if f.model not in rates:
            rates[f.model] = eval_rate(f, ground, args.threads)
        p = f.params
        quality = f"{p['raster_size']} px" if p["sampler"] == "raster" else f"{p['rays']} rays"
        rec = {
            **cfg,
            "resolution": f.resolution,
            "model": f.model,
            "prefilter": p["prefilter"],
            "quality": quality,
            "fit_s": seconds,
            "bytes": size,
            "rmse": rmse(ao, ref),
            "p99": float(np.percentile(err, 99)),
            "max": float(err.max()),
            "rmse_contact": rmse(ao[near], ref[near]),
            "residual_omega": f.omega_rms,
            "residual_y_deg": f.y_rms_degrees,
            "eval_mps": rates[f.model] / 1e6,
        }
        records.append(rec)
        rows.append(
            [
                p["sampler"],
                f.resolution,
                f.model,
                p["prefilter"],
                quality,
                f"{seconds:.1f}",
                f"{size:,}",
                f"{rec['rmse']:.4f}",
                f"{rec['p99']:.3f}",
                f"{rec['max']:.2f}",
                f"{rec['rmse_contact']:.4f}",
                f"{rec['eval_mps']:.1f}",
            ]
        )
        print(f"  done: {rows[-1]}", file=sys.stderr, flush=True)

    # the spherical-cap floor: exact Omega and Y at every receiver
    offset = 1e-4 * radius
    om, vec = raster_occlusion(bunny.positions, bunny.faces, ground + offset * normals, size=128)
    length = np.linalg.norm(vec, axis=1)
    ct = np.einsum("ij,ij->i", vec, normals) / np.where(length > 0, length, 1.0)
    cap = 1.0 - cap_integral(om, ct)
    cap_err = np.abs(cap - ref)
    rows.append(
        ["cap floor", "-", "exact Omega, Y", "-", "128 px", "-", "-", f"{rmse(cap, ref):.4f}",
         f"{np.percentile(cap_err, 99):.3f}", f"{cap_err.max():.2f}", f"{rmse(cap[near], ref[near]):.4f}", "-"]
    )  # fmt: skip

    headers = ["sampler", "N", "model", "prefilter", "sampler quality", "fit s", "bytes",
               "RMSE", "p99", "max", "RMSE contact", "eval M rcv/s"]  # fmt: skip
    print(f"\nbunny ({bunny.n_vertices} vertices, {bunny.n_faces} triangles) on a {CELLS + 1}^2 ground grid, "
          f"3 bounding radii wide; reference: Embree, {REFERENCE_RAYS} rays; contact ring: "
          f"{int(near.sum())} ground vertices within 0.2 radii of the hull; defaults: "
          f"15 radial samples, r_far = 8 radii\n")  # fmt: skip
    print(markdown_table(headers, rows, "lrllllrrrrrr"))
    print()
    for label, value in machine_facts():
        print(f"- {label}: {value}")
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    (RESULTS_DIR / "bench_field.json").write_text(json.dumps(records, indent=1))


if __name__ == "__main__":
    main()
