"""The disk method's light against the ray-traced reference (issue 16): relative RMSE of
``irradiance`` (and its direct and indirect terms) on the bundled Cornell-like box, with
its RectLight and as an emissive quad, for each shadowing variant, and the time of each
beside the reference method at its defaults.

    PYTHONPATH=. python bench/bench_bunnell_light.py [--ref-samples 4096] [--ref-paths 16384]

Goal: relative RMSE <= 0.08 at the defaults (aimed, two shadow passes, one bounce).
"published": every shadow pass as the GPU Gems 2 chapter's (isotropic), the vertex disks
occluding; "aimed": the emitted light's passes aimed at the lights (the bounced light's
passes as published), the vertex disks or the triangles occluding in all of them.
docs/bunnell-light.md records runs.
"""

from __future__ import annotations

import argparse
import time

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
    args = parser.parse_args()
    path = DATA_DIR / "cornell_box.usda"
    surface = load_mesh(path)
    shading = read_shading(path, surface)
    disk_light(surface, shading)  # compile
    irradiance(surface, shading, n_samples=1, n_indirect=1)
    print(f"scene {path.name}: {surface.n_vertices} vertices; reference {args.ref_samples} samples, "
          f"{args.ref_paths} paths; bunnell defaults: {SHADOW_PASSES} shadow passes, 1 bounce")
    for name, surf, sh, scored, ref, t_ref in references(surface, shading, args.ref_samples, args.ref_paths):
        t = time.perf_counter()
        emb = irradiance(surf, sh)
        t_emb = time.perf_counter() - t
        e_ref = ref.irradiance[:scored]
        print(f"{name}: embree defaults rel. RMSE {rel_rmse(emb.irradiance[:scored], e_ref):.4f} in {t_emb:.3f} s "
              f"(reference {t_ref:.1f} s)")
        schemes = {"published": {"aimed": False, "faces_occlude": False}, "aimed, disks occlude": {"faces_occlude": False}, "aimed, faces occlude": {}}
        for what, knobs in schemes.items():
            for disks in args.disks.split(","):
                for passes in args.passes.split(","):
                    if passes == "0" and knobs.get("aimed", True):
                        continue  # no shadow pass: the same as published
                    t = time.perf_counter()
                    r = disk_light(surf, sh, BunnellOptions(), shadow_passes=int(passes), light_disks=int(disks), **knobs)
                    dt = time.perf_counter() - t
                    print(f"  bunnell {what}, {passes} shadow passes, {disks} disks/light: rel. RMSE "
                          f"{rel_rmse(r.irradiance[:scored], e_ref):.4f} (direct {rel_rmse(r.direct[:scored], ref.direct[:scored]):.4f}, "
                          f"indirect {rel_rmse(r.indirect[:scored], ref.indirect[:scored]):.4f}); "
                          f"{r.negative} vertices set from negative to 0; {dt:.3f} s ({t_emb / dt:.2f}x embree's speed)")

if __name__ == "__main__":
    main()
