"""The disk method's light against the ray-traced reference (issue 16): relative RMSE of
``irradiance`` (and its direct and indirect terms) on the bundled Cornell-like box, with
its RectLight and as an emissive quad, for each shadowing variant, and the time of each
beside the reference method at its defaults.

    PYTHONPATH=. python bench/bench_bunnell_light.py [--ref-samples 4096] [--ref-paths 16384] [--near 0,4]
        [--max-distance D]

Goal: relative RMSE <= 0.08 at the defaults (aimed, two shadow passes, one bounce).
"published": every shadow pass as the GPU Gems 2 chapter's (isotropic), the vertex disks
occluding; "aimed": the emitted light's passes aimed at the lights (the bounced light's
passes as published), the vertex disks or the triangles occluding in all of them.
The default scheme is measured twice: through the cluster trees (the default) and with
the brute-force passes (``theta=None``). ``--big N`` instead bakes bench/common.py's
spheres on a floor at about N vertices under a rect light (or ``--big-light point``) with
both methods at their defaults: seconds and peak memory of each, in child processes.
``--relight N`` times re-lighting (``prepare_light`` / ``LitScene.light``) on those spheres
at about N vertices: a point light moved to six places (one bounce), alone and beside a
fixed rect light, each call against a fresh ``disk_light`` with the same lights (the
goal of issue 16: <= 0.2 s a call on 100k vertices). docs/bunnell-light.md records runs.
"""

from __future__ import annotations

import argparse
import itertools
import json
import resource
import subprocess
import sys
import time
from dataclasses import replace

from bench_light import references, rel_rmse

from aobake.io import load_mesh
from aobake.io.lights import read_shading
from aobake.methods.bunnell import BunnellOptions
from aobake.methods.bunnell.light import SHADOW_PASSES, disk_light
from aobake.methods.embree.light import irradiance

from common import DATA_DIR


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ref-samples", type=int, default=4096)
    parser.add_argument("--ref-paths", type=int, default=16384)
    parser.add_argument("--passes", default="0,1,2,3", help="shadow passes to measure")
    parser.add_argument("--disks", default="256", help="disks per area light to measure")
    parser.add_argument("--near", default="0,4", help="the triangles' near-field reach (trees, faces occlude) to measure")
    parser.add_argument("--max-distance", type=float, default=None,
                        help="cap both methods (and the reference) at this distance; the disk method's defaults also uncapped")  # fmt: skip
    parser.add_argument("--big", type=int, default=0, help="bake a lit scene of about N vertices instead")
    parser.add_argument("--big-light", default="rect", choices=("rect", "point"))
    parser.add_argument("--relight", type=int, default=0, help="time re-lighting a prepared scene of about N vertices")
    parser.add_argument("--repeats", type=int, default=3, help="--relight: rounds (best of)")
    parser.add_argument("--child", default="", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.relight:
        return relight(args.relight, args.repeats)
    if args.child:
        return child(args.child, args.big, args.big_light)
    if args.big:
        return big(args.big, args.big_light)
    path = DATA_DIR / "cornell_box.usda"
    surface = load_mesh(path)
    shading = read_shading(path, surface)
    disk_light(surface, shading)  # compile
    irradiance(surface, shading, n_samples=1, n_indirect=1)
    print(f"scene {path.name}: {surface.n_vertices} vertices; reference {args.ref_samples} samples, "
          f"{args.ref_paths} paths; bunnell defaults: {SHADOW_PASSES} shadow passes, 1 bounce")
    capped = {} if args.max_distance is None else {"max_distance": args.max_distance}
    for name, surf, sh, scored, ref, t_ref in references(surface, shading, args.ref_samples, args.ref_paths, **capped):
        t = time.perf_counter()
        emb = irradiance(surf, sh, **capped)
        t_emb = time.perf_counter() - t
        e_ref = ref.irradiance[:scored]
        print(f"{name}: embree defaults rel. RMSE {rel_rmse(emb.irradiance[:scored], e_ref):.4f} in {t_emb:.3f} s "
              f"(reference {t_ref:.1f} s)")
        if capped:
            free = disk_light(surf, sh).irradiance[:scored]
            print(f"  bunnell defaults, not capped: rel. RMSE {rel_rmse(free, e_ref):.4f} against the capped reference")
        schemes = {"published": {"aimed": False, "faces_occlude": False}, "aimed, disks occlude": {"faces_occlude": False},
                   "aimed, faces occlude (brute force)": {"theta": None}, "aimed, faces occlude": {}}  # fmt: skip
        for what, knobs in schemes.items():
            nears = args.near.split(",") if what == "aimed, faces occlude" else [None]
            for disks, passes, near in itertools.product(args.disks.split(","), args.passes.split(","), nears):
                if passes == "0" and knobs.get("aimed", True):
                    continue  # no shadow pass: the same as published
                kw = dict(knobs) if near is None else {**knobs, "near": float(near)}
                label = what if near is None else f"{what}, near {near}"
                t = time.perf_counter()
                r = disk_light(surf, sh, BunnellOptions(**capped), shadow_passes=int(passes), light_disks=int(disks), **kw)
                dt = time.perf_counter() - t
                print(f"  bunnell {label}, {passes} shadow passes, {disks} disks/light: rel. RMSE "
                      f"{rel_rmse(r.irradiance[:scored], e_ref):.4f} (direct {rel_rmse(r.direct[:scored], ref.direct[:scored]):.4f}, "
                      f"indirect {rel_rmse(r.indirect[:scored], ref.indirect[:scored]):.4f}); "
                      f"{r.negative} vertices set from negative to 0; {dt:.3f} s ({t_emb / dt:.2f}x embree's speed)")


def lit_scene(n, kind):
    """bench/common.py's spheres on a floor (z up, balls 2 tall) lit from above by a
    2 x 2 rect light at z = 3.5 (radiance 2), or a point light there (intensity 20)."""
    from aobake.shading import Light, default_shading

    import common

    s, desc = common.spheres_on_ground(n)
    if kind == "rect":
        light = Light.make("rect", "panel", (2.0,) * 3, position=(0.5, 0.3, 3.5), u=(1.0, 0, 0), v=(0, -1.0, 0))
    else:
        light = Light.make("point", "lamp", (20.0,) * 3, position=(0.5, 0.3, 3.5))
    return s, default_shading(s.n_vertices, s.n_faces, [light]), desc


def child(method, n, kind):
    """One method's bake of the lit scene in this process: prints seconds and peak RSS."""
    import numpy as np

    s, sh, _ = lit_scene(n, kind)
    t, c = time.perf_counter(), time.process_time()
    r = disk_light(s, sh) if method == "bunnell" else irradiance(s, sh)
    dt, cpu = time.perf_counter() - t, time.process_time() - c
    np.save(f"/tmp/bench_bunnell_light_{method}_{kind}_{n}.npy", r.irradiance)
    print(json.dumps({"seconds": dt, "cpu": cpu, "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                      "negative": int(getattr(r, "negative", 0))}))  # fmt: skip


def big(n, kind):
    import numpy as np

    _, _, desc = lit_scene(n, kind)  # cache the scene before timing
    print(f"scene: {desc}, {kind} light; each method in its own process (kernels cached)")
    out = {}
    for method in ("bunnell", "embree"):
        cmd = [sys.executable, __file__, "--child", method, "--big", str(n), "--big-light", kind]
        run = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout.strip().splitlines()[-1])
        out[method] = np.load(f"/tmp/bench_bunnell_light_{method}_{kind}_{n}.npy")
        print(f"  {method} defaults: {run['seconds']:.2f} s ({run['cpu']:.2f} s of CPU), peak RSS {run['peak_mb']:.0f} MB"
              + (f", {run['negative']} vertices set from negative to 0" if method == "bunnell" else ""))
    print(f"  bunnell against embree's defaults: rel. RMSE {rel_rmse(out['bunnell'], out['embree']):.4f}")


def relight(n, repeats):
    """Time per re-lighting call (wall and CPU, best of ``repeats`` rounds of six moved
    lamps) and the set-up, against a fresh disk_light per light set; the same bits."""
    import numpy as np

    from aobake.methods.bunnell.light import prepare_light
    from aobake.shading import Light

    from common import interleaved, timed

    s, sh, desc = lit_scene(n, "rect")
    rect = sh.lights
    lamps = [Light.make("point", "lamp", (20.0,) * 3, position=(2.5 * np.cos(a), 2.5 * np.sin(a), 3.0))
             for a in np.linspace(0, 2 * np.pi, 6, endpoint=False)]  # fmt: skip
    disk_light(s, sh)  # compile
    print(f"scene: {desc}; a point light (intensity 20) moved to six places 3 above the floor, one bounce")
    for what, fixed in (("lamp alone", ()), ("lamp beside the rect light", rect)):
        prep = timed(lambda fixed=fixed: prepare_light(s, sh).light((*fixed, lamps[0])))
        scene = prepare_light(s, sh)
        first = timed(lambda scene=scene, fixed=fixed: scene.light((*fixed, lamps[0])))
        t = interleaved({"relight": lambda scene=scene, fixed=fixed: [scene.light((*fixed, lamp)) for lamp in lamps]}, repeats)
        some = lamps[:2]  # a fresh bake with the rect light takes seconds: two of them
        fresh = timed(lambda fixed=fixed, some=some: [disk_light(s, replace(sh, lights=(*fixed, lamp))) for lamp in some])
        same = all(np.array_equal(a.irradiance, b.irradiance) for a, b in zip(t["relight"].result[: len(some)], fresh.result, strict=True))
        k = len(lamps)
        call, call_cpu = t["relight"].seconds / k, t["relight"].cpu / k
        print(f"  {what}: prepare + first call {prep.seconds:.3f} s ({prep.cpu:.3f} s CPU), the first call on a prepared "
              f"scene {first.seconds:.3f} s; a re-lighting call {call:.3f} s wall ({call_cpu:.3f} s CPU, best of "
              f"{t['relight'].repeats}); a fresh disk_light {fresh.seconds / len(some):.3f} s ({fresh.cpu / len(some):.3f} s "
              f"CPU): {fresh.seconds / len(some) / call:.1f}x; results {'bit-identical' if same else 'DIFFER'}")


if __name__ == "__main__":
    main()
