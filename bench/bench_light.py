"""Light transport bench (issue 15): ray throughput of the shadow and bounce rays against
the AO rays on the same scene, accuracy at the defaults against a high-sample estimate
on the bundled Cornell-like box (its RectLight, and the same light as an emissive quad),
and coverage of the per-vertex error estimate.

    PYTHONPATH=. python bench/bench_light.py [--repeats 3] [--threads 2]
    PYTHONPATH=. python bench/bench_light.py --against CHECKOUT [--rounds 6]

Prints ratios measured in one run (goals: throughput >= 0.9x the AO rays', relative RMSE
<= 2%, coverage >= 95%), the throughput also as CPU time a ray on one thread (the
work a ray costs, steadier than wall time on a shared machine); docs/bench_light.md
records runs. ``--against`` measures only the throughput, of another checkout (say main)
and of this one, alternating in fresh processes round after round so the load the
machine carries hits both alike, and prints each round's ratios and their medians.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from aobake.io import load_mesh
from aobake.io.lights import read_shading
from aobake.mesh import surface_from_arrays
from aobake.methods.embree import embree_ao
from aobake.methods.embree.light import irradiance
from aobake.methods.embree.options import LightOptions
from aobake.shading import Shading

from common import DATA_DIR


def emissive_variant(surface, shading):
    """The box with its RectLight replaced by a two-triangle quad emitting the same
    radiance downwards (the quad also occludes; its 4 vertices are not scored)."""
    light = next(x for x in shading.lights if x.kind == "rect")
    corners = [light.position + su * light.u + sv * light.v for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    n = surface.n_vertices
    quad = np.array([[n, n + 1, n + 2], [n, n + 2, n + 3]])
    if np.dot(np.cross(corners[1] - corners[0], corners[2] - corners[0]), light.normal) < 0:
        quad = quad[:, ::-1]
    pos = np.vstack([surface.positions, corners])
    normals = np.vstack([surface.normals, np.tile(light.normal, (4, 1))])
    out = surface_from_arrays(pos, np.vstack([surface.faces, quad]), normals)
    lights = tuple(x for x in shading.lights if x is not light)
    emission = np.vstack([shading.face_emission, np.tile(light.value, (2, 1))])
    albedo = np.vstack([shading.face_albedo, np.zeros((2, 3))])
    return out, Shading(
        lights, albedo, emission, np.vstack([shading.vertex_albedo, np.zeros((4, 3))]),
        np.vstack([shading.vertex_emission, np.tile(light.value, (4, 1))]),
    ), n  # fmt: skip


def references(surface, shading, samples, paths, **changes):
    """``(name, surface, shading, scored vertices, reference, its seconds)`` of the box with
    its RectLight and as an emissive quad: the high-sample estimates the light benches
    measure against (``changes``: more of ``irradiance``'s options, e.g. ``max_distance``)."""
    for name, (surf, sh, scored) in {
        "RectLight": (surface, shading, surface.n_vertices),
        "emissive quad": emissive_variant(surface, shading),
    }.items():
        t = time.perf_counter()
        ref = irradiance(surf, sh, n_samples=samples, n_indirect=paths, seed=12345, **changes)
        yield name, surf, sh, scored, ref, time.perf_counter() - t


def rel_rmse(a, b):
    return float(np.sqrt(((a - b) ** 2).sum() / (b**2).sum()))


def throughput(surface, shading, repeats, threads):
    """Best-of-``repeats`` rays per second of AO, direct-only and one-bounce runs, interleaved."""
    best = {"ao": 0.0, "shadow": 0.0, "bounce": 0.0}
    for _ in range(repeats):
        t = time.perf_counter()
        ao = embree_ao(surface, n_rays=1024, threads=threads)
        best["ao"] = max(best["ao"], ao.n_rays / (time.perf_counter() - t))
        t = time.perf_counter()
        r = irradiance(surface, shading, n_samples=1024, bounces=0, threads=threads)
        best["shadow"] = max(best["shadow"], r.n_shadow_rays / (time.perf_counter() - t))
        t = time.perf_counter()
        r = irradiance(surface, shading, n_samples=16, n_indirect=1024, bounces=1, threads=threads)
        best["bounce"] = max(best["bounce"], (r.n_shadow_rays + r.n_bounce_rays) / (time.perf_counter() - t))
    return best


def cpu_per_ray(surface, shading, repeats):
    """Best-of-``repeats`` CPU nanoseconds a ray of the same three runs on one thread:
    the work a ray costs, whatever else the machine runs at the time."""
    best = {"ao": np.inf, "shadow": np.inf, "bounce": np.inf}
    for _ in range(repeats):
        t = time.process_time()
        ao = embree_ao(surface, n_rays=1024, threads=1)
        best["ao"] = min(best["ao"], (time.process_time() - t) / ao.n_rays * 1e9)
        t = time.process_time()
        r = irradiance(surface, shading, n_samples=1024, bounces=0, threads=1)
        best["shadow"] = min(best["shadow"], (time.process_time() - t) / r.n_shadow_rays * 1e9)
        t = time.process_time()
        r = irradiance(surface, shading, n_samples=16, n_indirect=1024, bounces=1, threads=1)
        best["bounce"] = min(best["bounce"], (time.process_time() - t) / (r.n_shadow_rays + r.n_bounce_rays) * 1e9)
    return best


def trace_only(surface, repeats):
    """Nanoseconds a ray of Embree's any-hit (AO) and closest-hit (path) queries alone, one
    thread, on the same rays: 1,024 cosine-weighted rays a vertex from the AO's origins."""
    from aobake.contacts import contact_origins, ray_offsets
    from aobake.kernels import rays as _k
    from aobake.kernels import topology as _topo
    from aobake.tracing import Tracer

    tracer = Tracer(surface.positions, surface.faces)
    edges = _topo.longest_edges(surface.positions, surface.faces)
    origins, _ = contact_origins(surface, tracer, ray_offsets(surface, tracer.magnitude, None, edges), edges)
    keys = _k.vertex_keys(np.uint64(0), surface.n_vertices)
    vertices = np.arange(surface.n_vertices, dtype=np.int64)
    org = np.empty((vertices.size * 1024, 3), dtype=np.float32)
    dirs = np.empty_like(org)
    _k.generate_rays(origins, np.ascontiguousarray(surface.normals), keys, vertices, 0, 1024, 0, org, dirs)
    best = {"any": np.inf, "closest": np.inf}
    for _ in range(repeats):
        for name, query in (("any", tracer.occluded), ("closest", tracer.first_hits)):
            t = time.perf_counter()
            for s in range(0, org.shape[0], 8192):
                query(org[s : s + 8192], dirs[s : s + 8192])
            best[name] = min(best[name], (time.perf_counter() - t) / org.shape[0] * 1e9)
    return best


def ratios(surface, shading, repeats, threads):
    """Wall rates (all threads) and CPU time a ray (one thread) as ratios to the AO's."""
    rates = throughput(surface, shading, repeats, threads)
    cpu = cpu_per_ray(surface, shading, repeats)
    return {
        "wall shadow": rates["shadow"] / rates["ao"],
        "wall bounce": rates["bounce"] / rates["ao"],
        "cpu shadow": cpu["ao"] / cpu["shadow"],
        "cpu bounce": cpu["ao"] / cpu["bounce"],
        "ao rays/s": rates["ao"],
        "cpu ao ns": cpu["ao"],
        "aobake": str(Path(sys.modules["aobake"].__file__).parent.parent),
    }


def against(other: str, rounds: int, repeats: int, threads):
    """Throughput ratios of ``other`` (a checkout) and of this one, alternating in fresh
    processes: the first run of each compiles nothing that is cached."""
    this = str(Path(__file__).resolve().parent.parent)
    other = str(Path(other).resolve())
    extra = ["--repeats", str(repeats)] + ([] if threads is None else ["--threads", str(threads)])
    runs = {"other": [], "this": []}
    print(f"load average at the start: {os.getloadavg()[0]:.1f}; other = {other}, this = {this}")
    for r in range(rounds + 1):  # round 0 warms both numba caches and is not counted
        for label, root in (("other", other), ("this", this)):
            env = dict(os.environ, PYTHONPATH=root)
            out = subprocess.run(
                [sys.executable, __file__, "--ratios-only", *extra], env=env, check=True, capture_output=True, text=True
            ).stdout
            if r == 0:
                print(f"{label}: aobake from {json.loads(out.strip().splitlines()[-1])['aobake']}")
                continue
            got = json.loads(out.strip().splitlines()[-1])
            runs[label].append(got)
            print(f"round {r} {label:5s}: wall shadow {got['wall shadow']:.3f}x, bounce {got['wall bounce']:.3f}x; "
                  f"cpu a ray shadow {got['cpu shadow']:.3f}x, bounce {got['cpu bounce']:.3f}x "
                  f"(AO {got['ao rays/s']:.3g} rays/s, {got['cpu ao ns']:.1f} ns)  load {os.getloadavg()[0]:.1f}", flush=True)  # fmt: skip
    for key in ("wall shadow", "wall bounce", "cpu shadow", "cpu bounce"):
        a = np.median([g[key] for g in runs["other"]])
        b = np.median([g[key] for g in runs["this"]])
        print(f"median {key}: other {a:.3f}x, this {b:.3f}x")
    print(f"load average at the end: {os.getloadavg()[0]:.1f}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--ref-samples", type=int, default=4096)
    parser.add_argument("--ref-paths", type=int, default=16384)
    parser.add_argument("--against", metavar="CHECKOUT", help="compare the throughput with another checkout's")
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--ratios-only", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.against:
        return against(args.against, args.rounds, args.repeats, args.threads)
    path = DATA_DIR / "cornell_box.usda"
    surface = load_mesh(path)
    shading = read_shading(path, surface)
    if args.ratios_only:
        irradiance(surface, shading, n_samples=1, n_indirect=1)  # compile
        print(json.dumps(ratios(surface, shading, args.repeats, args.threads)))
        return None
    defaults = LightOptions()
    print(f"scene {path.name}: {surface.n_vertices} vertices, {surface.n_faces} triangles; defaults "
          f"n_samples {defaults.n_samples}, n_indirect {defaults.n_indirect}, bounces {defaults.bounces}")
    irradiance(surface, shading, n_samples=1, n_indirect=1)  # compile
    rates = throughput(surface, shading, args.repeats, args.threads)
    print(f"rays/s: ao {rates['ao']:.3g}, shadow {rates['shadow']:.3g} ({rates['shadow'] / rates['ao']:.2f}x), "
          f"bounce+nee {rates['bounce']:.3g} ({rates['bounce'] / rates['ao']:.2f}x)  [goal >= 0.9x]")
    cpu = cpu_per_ray(surface, shading, args.repeats)
    print(f"cpu per ray, 1 thread: ao {cpu['ao']:.1f} ns, shadow {cpu['shadow']:.1f} ns ({cpu['ao'] / cpu['shadow']:.2f}x), "
          f"bounce+nee {cpu['bounce']:.1f} ns ({cpu['ao'] / cpu['bounce']:.2f}x)")
    ns = trace_only(surface, args.repeats)
    print(f"trace only, 1 thread, same rays: any-hit {ns['any']:.1f} ns/ray, closest-hit {ns['closest']:.1f} ns/ray "
          f"({ns['any'] / ns['closest']:.2f}x the any-hit rate)")
    for name, surf, sh, scored, ref, t_ref in references(surface, shading, args.ref_samples, args.ref_paths):
        r = irradiance(surf, sh)
        e, e_ref = r.irradiance[:scored], ref.irradiance[:scored]
        covered = np.all(np.abs(e - e_ref) <= r.error[:scored], axis=1).mean()
        print(f"{name}: relative RMSE {rel_rmse(e, e_ref):.4f} (direct {rel_rmse(r.direct[:scored], ref.direct[:scored]):.4f}, "
              f"indirect {rel_rmse(r.indirect[:scored], ref.indirect[:scored]):.4f}) [goal <= 0.02]; "
              f"error estimate covers {covered:.3f} of vertices [goal >= 0.95]; "
              f"{r.seconds:.2f} s, {r.n_shadow_rays + r.n_bounce_rays:,} rays (reference {t_ref:.1f} s)")


if __name__ == "__main__":
    main()
