"""Ray-cast references in float64 numpy, independent of Embree and of the kernels:
Moller-Trumbore visibility (two-sided triangles) and Monte Carlo AO from it."""

from __future__ import annotations

import numpy as np


def ray_hits_any(origins, directions, triangles, tfar=np.inf, eps=1e-12) -> np.ndarray:
    """Moller-Trumbore in float64: (k,) bool, does ray k hit any triangle at t in [0, tfar]?

    Parameters
    ----------
    origins, directions : (k, 3) float
    triangles : (m, 3, 3) float
    """
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    v0, v1, v2 = (np.asarray(triangles, dtype=np.float64)[:, i] for i in range(3))
    e1, e2 = v1 - v0, v2 - v0
    hit = np.zeros(len(o), dtype=bool)
    for start in range(0, len(o), 256):
        oo, dd = o[start : start + 256, None, :], d[start : start + 256, None, :]
        p = np.cross(dd, e2[None])
        det = np.einsum("kmj,mj->km", p, e1)
        ok = np.abs(det) > eps
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = oo - v0[None]
        u = np.einsum("kmj,kmj->km", s, p) * inv
        q = np.cross(s, e1[None])
        v = np.einsum("kmj,kmj->km", dd, q) * inv
        t = np.einsum("kmj,mj->km", q, e2) * inv
        h = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= tfar)
        hit[start : start + 256] = h.any(axis=1)
    return hit


def reference_ao(surface, origins, directions, tfar=np.inf) -> np.ndarray:
    """AO (1 - hits / N) from given per-vertex origins (n, 3) and directions (n, N, 3)."""
    n, n_rays, _ = directions.shape
    tris = surface.positions[surface.faces]
    org = np.repeat(np.asarray(origins, dtype=np.float64), n_rays, axis=0)
    hits = ray_hits_any(org, directions.reshape(-1, 3), tris, tfar)
    return 1.0 - hits.reshape(n, n_rays).mean(axis=1)


def cosine_directions(normal: np.ndarray, n_rays: int, rng: np.random.Generator) -> np.ndarray:
    """Stratified cosine-weighted directions about ``normal`` (Malley's method)."""
    side = int(np.ceil(np.sqrt(n_rays)))
    i, j = np.divmod(np.arange(side * side), side)
    u1 = (i + rng.random(side * side)) / side
    u2 = (j + rng.random(side * side)) / side
    rad = np.sqrt(u1)
    phi = 2 * np.pi * u2
    local = np.c_[rad * np.cos(phi), rad * np.sin(phi), np.sqrt(np.maximum(0.0, 1 - u1))]
    helper = np.array([1.0, 0, 0]) if abs(normal[0]) < 0.9 else np.array([0, 1.0, 0])
    t = np.cross(normal, helper)
    t /= np.linalg.norm(t)
    b = np.cross(normal, t)
    return local @ np.array([t, b, normal])


def raycast_ao(surface, n_rays=256, seed=0, max_distance=None, offset=1e-6, vertices=None):
    """Cosine-weighted Monte Carlo accessibility ``1 - hits / N`` (two-sided triangles).

    Origins are offset by ``offset * bbox diagonal`` along the normal. Vertices without a
    normal get NaN. ``vertices`` restricts the receivers (default: all).
    """
    rng = np.random.default_rng(seed)
    p = surface.positions
    diag = np.linalg.norm(p.max(0) - p.min(0))
    tri = p[surface.faces]
    t_max = np.inf if max_distance is None else max_distance
    idx = np.arange(len(p)) if vertices is None else np.asarray(vertices)
    out = np.full(len(idx), np.nan)
    for k, i in enumerate(idx):
        n = surface.normals[i]
        if not n.any():
            continue
        dirs = cosine_directions(n, n_rays, rng)
        origins = np.repeat((p[i] + offset * diag * n)[None], len(dirs), axis=0)
        out[k] = 1.0 - ray_hits_any(origins, dirs, tri, t_max).mean()
    return out
