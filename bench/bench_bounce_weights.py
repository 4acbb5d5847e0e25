"""The bounce's shadow passes: what weights an occluder's subtraction (issue 16's negative
light). Brute force in numpy on small scenes, against the ray-traced indirect irradiance.

    cd bench && PYTHONPATH=..:. python bench_bounce_weights.py [--vertices 2500]

"published": occluder j blocks ``E/pi`` of the light on its far side, as if that light
arrived alike from every direction (``disk_light(theta=None)``'s passes, checked equal
here). "directional": each side also carries its light's first moment ``F = sum E_i u_i``
(u: the direction the light comes from), and j blocks the radiance of the linear model
``L(w) = c0 + c1.w`` (clamped at 0) that matches ``E`` and ``F`` over the side's
hemisphere, taken along the direction from the receiver through j. A prototype: it is not
in the trees; docs/bunnell-light.md records its runs.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from bench_light import rel_rmse

from aobake.io import load_mesh
from aobake.io.lights import read_shading
from aobake.methods.bunnell import light as disk
from aobake.methods.bunnell.elements import build_elements
from aobake.methods.embree.light import irradiance

from common import DATA_DIR


def gather(points, normals, centres, disk_normals, areas, radiance=None, *, own=None, radiance_of=None, chunk=128):
    """(n, 3) irradiance and (n, 3, 3) its first moment at the receivers from one-sided
    disks, the transfer's terms ``pi L A cos_e cos_r / (pi r^2 + A)``; ``radiance_of(u)``
    (r, k, 3) for radiance that depends on the direction u (r, k, 3) toward each disk."""
    n = len(points)
    e, f = np.zeros((n, 3)), np.zeros((n, 3, 3))
    for s in range(0, n, chunk):
        p, nr = points[s : s + chunk], normals[s : s + chunk]
        d = centres[None] - p[:, None]
        r2 = (d * d).sum(-1)
        r = np.sqrt(r2)
        u = d / np.where(r > 0, r, 1.0)[..., None]
        cos_r = (u * nr[:, None]).sum(-1)
        cos_e = -(u * disk_normals[None]).sum(-1)
        g = np.where((cos_r > 0) & (cos_e > 0), areas[None] * cos_e * cos_r / (math.pi * r2 + areas[None]), 0.0)
        if own is not None:
            g[np.arange(len(p))[:, None] + s == own[None]] = 0.0
        c = math.pi * g[..., None] * (radiance[None] if radiance_of is None else radiance_of(u))
        e[s : s + chunk] = c.sum(1)
        f[s : s + chunk] = np.einsum("rkc,rkx->rcx", c, u)
    return e, f


def linear_model(e, f, normals):
    """``c0`` (n, 3), ``c1`` (n, 3, 3) of ``L(w) = c0 + c1.w`` whose irradiance and first
    moment over the hemisphere of ``normals`` are ``e`` and ``f`` (exact for constant L)."""
    fn = np.einsum("ncx,nx->nc", f, normals)
    c0 = (9 * e - 12 * fn) / math.pi
    c1n = (18 * fn - 12 * e) / math.pi
    c1 = 4 / math.pi * (f - fn[..., None] * normals[:, None, :]) + c1n[..., None] * normals[:, None, :]
    return c0, c1


def bounce(elements, radiance, passes, mode):
    """The front sides' bounce (not clamped) after ``passes`` shadow passes, triangles occluding."""
    idx = elements.emitter_index
    fp, fn, bp, bn = disk._sides(elements)
    src = (elements.positions[idx], elements.normals[idx], elements.areas[idx], radiance[idx])
    sides = ((fp, fn), (bp, bn))
    first = [gather(p, n, *src, own=idx) for p, n in sides]
    faces, occ = disk._face_occluders(elements)
    centres, normals, areas = occ[:, :3], occ[:, 3:6], occ[:, 6]
    now = first
    for _ in range(passes):
        (e_f, f_f), (e_b, f_b) = now
        if mode == "published":
            w_b, w_f = (np.maximum(e, 0.0)[faces].mean(axis=1) / math.pi for e in (e_b, e_f))
            blocked = [(gather(p, n, centres, normals, areas, w_b), gather(p, n, centres, -normals, areas, w_f)) for p, n in sides]
        else:
            mf = [a[faces].mean(axis=1) for a in linear_model(np.maximum(e_f, 0.0), f_f, fn)]
            mb = [a[faces].mean(axis=1) for a in linear_model(np.maximum(e_b, 0.0), f_b, bn)]

            def along(m):
                return lambda u: np.maximum(m[0][None] + np.einsum("kcx,rkx->rkc", m[1], u), 0.0)

            blocked = [(gather(p, n, centres, normals, areas, radiance_of=along(mb)),
                        gather(p, n, centres, -normals, areas, radiance_of=along(mf))) for p, n in sides]  # fmt: skip
        now = [(e0 - a[0] - b[0], f0 - a[1] - b[1]) for (e0, f0), (a, b) in zip(first, blocked, strict=True)]
    return now[0][0]


def scenes(n):
    import bench_bunnell_light as bbl

    path = DATA_DIR / "cornell_box.usda"
    box = load_mesh(path)
    yield "the box, RectLight", box, read_shading(path, box)
    for kind in ("point", "rect"):
        s, sh, desc = bbl.lit_scene(n, kind)
        yield f"{desc}, {kind} light", s, sh


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vertices", type=int, default=2500, help="the spheres scene's size")
    parser.add_argument("--passes", type=int, default=disk.SHADOW_PASSES)
    args = parser.parse_args()
    for name, s, sh in scenes(args.vertices):
        t = time.perf_counter()
        ref = irradiance(s, sh, n_samples=1024, n_indirect=8192, seed=5)
        brute = disk.disk_light(s, sh, theta=None, shadow_passes=args.passes)
        print(f"{name}: {s.n_vertices} vertices; reference 1,024 samples, 8,192 paths ({time.perf_counter() - t:.0f} s); "
              f"the bounce is {ref.indirect.sum() / ref.irradiance.sum():.3f} of the light")  # fmt: skip
        radiance = np.asarray(sh.vertex_albedo) * brute.direct / math.pi
        for mode in ("published", "directional"):
            e = bounce(build_elements(s), radiance, args.passes, mode)
            kept = np.maximum(e, 0.0)
            same = f"; equals disk_light(theta=None) to {np.abs(kept - brute.indirect).max():.1e}" if mode == "published" else ""
            print(f"  {mode}: indirect rel. RMSE {rel_rmse(kept, ref.indirect):.4f}; {np.any(e < 0, axis=1).sum()} vertices "
                  f"below zero, the clamp adding {-np.minimum(e, 0).sum() / kept.sum():.3f} of the bounce; mean "
                  f"{kept.sum() / ref.indirect.sum():.3f} of the reference's{same}")  # fmt: skip


if __name__ == "__main__":
    main()
