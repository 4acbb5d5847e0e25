"""Slow, obviously correct numpy reference of the disk method (aobake.bunnell).

Nothing here imports aobake's kernels: the disk areas, the O(n^2) sums and the passes are
written again from the formulas, one receiver at a time. Small meshes only (<= ~3k
vertices).
"""

from __future__ import annotations

import numpy as np

from aobake.mesh import Surface

from .closed_forms import polygon_form_factor, polygon_solid_angle


def naive_vertex_areas(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """A third of each triangle's area (0.5 |e1 x e2|) to each of its corners, face by face."""
    areas = np.zeros(len(positions))
    for a, b, c in faces:
        tri_area = 0.5 * np.linalg.norm(
            np.cross(positions[b] - positions[a], positions[c] - positions[a])
        )
        areas[a] += tri_area / 3.0
        areas[b] += tri_area / 3.0
        areas[c] += tri_area / 3.0
    return areas


def naive_cell(positions, faces, j, point, normal, measure="cosine"):
    """(front, back) of vertex j's barycentric cell at a receiver: per triangle around j
    (``faces``: those triangles, or all), the quad (j, edge midpoint, centroid, edge
    midpoint); skipped when the receiver lies within 1e-6 edge lengths of the triangle's
    plane."""
    front = back = 0.0
    fn = polygon_form_factor if measure == "cosine" else polygon_solid_angle
    for f in faces:
        if j not in f:
            continue
        k = list(f).index(j)
        a, b, c = positions[f[k]], positions[f[(k + 1) % 3]], positions[f[(k + 2) % 3]]
        m = np.cross(b - a, c - a)
        area2 = np.linalg.norm(m)
        if area2 == 0:
            continue
        h = np.dot(m, point - a) / area2
        if abs(h) <= 1e-6 * np.sqrt(area2):
            continue
        value = fn([a, (a + b) / 2, (a + b + c) / 3, (a + c) / 2], point, normal)
        if h > 0:
            front += value
        else:
            back += value
    return front, back


def naive_sums(
    positions,
    normals,
    areas,
    faces,
    points,
    weights,
    measure="cosine",
    max_distance=None,
    near=0.0,
    cell_weights=None,
    radii=None,
    reach=np.inf,
    occluders=None,
    gate=0.0,
    first=None,
    sectors=0,
    plain=None,
    keep=None,
    fill=None,
):
    """Unsaturated (front, back) sums at every vertex, one receiver at a time.

    Emitters: vertices with area > 0 and a nonzero normal, disk centres ``positions``;
    receivers at ``points``. Skipped: the receiver itself, emitters farther than
    max_distance, zero weights. Near field (a receiver with a normal and
    ``r^2 < near A``, decided in float32 like the kernels): the emitter's cell
    (:func:`naive_cell`) times its cell weight. Otherwise the disk: skipped when
    coincident (r^2 <= 1e-12 A); a receiver without a normal uses the mean receiver
    weight (1/4 cosine, 1/2 uniform); ``front`` when the emitter faces the receiver.

    ``weights`` (n,) or, with ``radii`` (ascending), (n, len(radii) + 1): the disk of j
    at distance r then weighs ``weights[j, #{R in radii : reach r >= R}]``. Returns
    (n, 2), or with ``radii`` (n, 2, len(radii)): cumulative, bin b summing the
    emitters with ``r < radii[b]``.

    ``occluders`` (n, 3) and ``gate`` > 0: a disk whose weight is below 1 only loses
    the fraction ``clamp(n_i.(occluders[j] - p_i) / (gate r), 0, 1)`` of ``1 - w``
    (1 for a receiver without a normal). ``first`` (n, 3): filled with
    ``sum term (c_j - p_i)`` over every disk and cell term (weighted).

    ``sectors`` S > 0 (cosine, receivers with a normal): every counted disk term but
    the wide ones (``A >= r^2``) is spread over 2 S direction bins of its side (S azimuth sectors of the receiver's
    tangent frame, linearly interpolated, times a near-normal / near-horizon split), and
    each side's total (the last bin with ``radii``) loses ``sum max(bin - 1 / 2S, 0)``;
    other bins and ``first`` stay unsaturated. ``plain`` (n, 2): filled with the totals
    before that subtraction. ``keep`` (n, 2, 2 S): filled with every receiver's direction
    bins. ``fill`` (n, 2, 2 S): pass 1's bins; each bin then gives back
    ``(v1 - v) v1 / c`` of what this pass removed (v1, v: pass 1's and this pass's
    content, each capped at the bin's measure c; none when v > v1).
    """
    positions = np.asarray(positions, dtype=np.float64)
    cell_weights = weights if cell_weights is None else cell_weights
    n = len(positions)
    casts = (areas > 0) & (np.linalg.norm(normals, axis=1) > 0)
    radii = None if radii is None else np.asarray(radii, dtype=float)
    bins = 1 if radii is None else len(radii)
    out = np.zeros((n, 2, bins))
    p32, a32 = positions.astype(np.float32), areas.astype(np.float32)
    around = [[] for _ in range(n)]
    for f in np.asarray(faces):
        for v in set(f.tolist()):
            around[v].append(f)
    for i in range(n):
        p = points[i]
        has_normal = np.linalg.norm(normals[i]) > 0
        saturate = sectors > 0 and has_normal and measure == "cosine"
        if saturate:
            u, v = tangent_frame(normals[i])
            directions = np.zeros((2, 2 * sectors))  # (side, sector + sectors * horizon)
        d32 = p32 - p.astype(np.float32)
        r2_32 = (d32 * d32).sum(axis=1, dtype=np.float32)
        for j in np.flatnonzero(casts):
            if j == i:
                continue
            d = positions[j] - p
            r2 = d @ d
            if max_distance is not None and r2 > max_distance**2:
                continue
            r = np.sqrt(r2)
            reached = slice(0, bins) if radii is None else (r < radii)
            if has_normal and r2_32[j] < np.float32(near) * a32[j]:
                f, b = naive_cell(positions, around[j], j, p, normals[i], measure)
                out[i][:, reached] += cell_weights[j] * np.array([f, b])[:, None]
                if first is not None:
                    first[i] += cell_weights[j] * (f + b) * d
                continue
            w = weights[j] if radii is None else weights[j, np.sum(reach * r >= radii)]
            if gate > 0 and occluders is not None and w < 1:
                lift = normals[i] @ (occluders[j] - p)
                g = np.clip(lift / (gate * r), 0.0, 1.0) if has_normal else 1.0
                w = 1.0 - (1.0 - w) * g
            if r2 <= 1e-12 * areas[j] or w <= 0:
                continue
            cos_e = -normals[j] @ d / r
            cos_r = normals[i] @ d / r
            a = areas[j]
            if measure == "cosine":
                g = max(cos_r, 0.0) if has_normal else 0.25
                term = a * abs(cos_e) * g / (np.pi * r2 + a)
            else:
                g = np.clip(4.0 * cos_r, 0.0, 1.0) if has_normal else 0.5
                term = (1.0 - r / np.sqrt(a / np.pi + r2)) * abs(cos_e) * g
            out[i][0 if cos_e > 0 else 1, reached] += w * term
            if first is not None:
                first[i] += w * term * d
            # wide disks (A >= r^2, aobake.constants.DIRECTION_WIDE) are not binned
            if saturate and (radii is None or r < radii[-1]) and areas[j] < r2:
                local = (u @ d, v @ d, normals[i] @ d)
                spread_direction(directions[0 if cos_e > 0 else 1], w * term, local, r2, sectors)
        if plain is not None:
            plain[i] = out[i, :, -1]
        if saturate:
            cap = 1.0 / (2 * sectors)
            excess = np.maximum(directions - cap, 0.0).sum(axis=1)
            out[i, :, -1] -= excess
            if keep is not None:
                keep[i] = directions
            if fill is not None:
                v1 = np.minimum(fill[i], cap)
                out[i, :, -1] += (np.maximum(v1 - np.minimum(directions, cap), 0.0) * v1 / cap).sum(
                    axis=1
                )
    return out[:, :, 0] if radii is None else out


def tangent_frame(normal):
    """(u, v) completing the unit ``normal`` to an orthonormal frame (Duff et al. 2017)."""
    nx, ny, nz = normal
    s = 1.0 if nz >= 0 else -1.0
    a = -1.0 / (s + nz)
    b = nx * ny * a
    u = np.array([1.0 + s * nx * nx * a, s * b, -s * nx])
    v = np.array([b, s + ny * ny * a, -ny])
    return u, v


def spread_direction(bins, value, local, r2, sectors):
    """Add ``value`` from direction ``local`` = (x, y, z) (tangent frame, r2 = |local|^2) to the
    2 S ``bins`` of one side: the pole share ``clip(1 - 16 sin^2, 0, 1)`` evenly over the
    sectors, the rest linear between the two nearest of S azimuth sectors (a pseudo-angle
    in [0, 4)); bins S.. getting the horizon fraction ``clip(1.5 - 2 z^2 / r2, 0, 1)``,
    bins 0.. the rest."""
    x, y, z = local
    fe = np.clip(1.5 - 2.0 * z * z / r2, 0.0, 1.0)
    pole = np.clip(1.0 - 16.0 * (x * x + y * y) / r2, 0.0, 1.0)
    for k in range(sectors):
        bins[k] += value * pole / sectors * (1 - fe)
        bins[sectors + k] += value * pole / sectors * fe
    value = value * (1.0 - pole)
    t = 0.0 if abs(x) + abs(y) == 0 else abs(y) / (abs(x) + abs(y))
    if y >= 0:
        q = t if x >= 0 else 2.0 - t
    else:
        q = 2.0 + t if x < 0 else 4.0 - t
    fa = q * sectors / 4.0 - 0.5
    k0 = int(np.floor(fa))
    wgt = fa - k0
    i0, i1 = k0 % sectors, (k0 + 1) % sectors
    bins[i0] += value * (1 - wgt) * (1 - fe)
    bins[i1] += value * wgt * (1 - fe)
    bins[sectors + i0] += value * (1 - wgt) * fe
    bins[sectors + i1] += value * wgt * fe


def naive_bunnell_ao(
    surface: Surface,
    passes=2,
    measure="cosine",
    max_distance=None,
    combine="last",
    near=0.0,
    sides="max",
    damping=1.0,
    pass_reach=0.5,
    gate=0.1,
    sectors=0,
    pass_fill=True,
):
    """Exact (no hierarchy) multi-pass disk AO, straight from the definitions.

    Coordinates are normalised like the kernels' (bounding-box centre and largest
    extent); receivers sit 1e-4 sqrt(A) above their vertex along the normal; in pass k
    the disk of j at distance r weighs ``1 - damping A_{k-1}(j; R)``, its occlusion by
    emitters closer than the largest of PASS_RADII that is <= pass_reach r (1 when none
    is); cell weights 1. With ``gate`` > 0 that occlusion only counts in the fraction
    ``clamp(n_i.(o_j - p_i) / (gate r), 0, 1)``, o_j the centroid of pass 1's terms at j
    (``p_j + sum term d / sum term``). ``sectors`` > 0 saturates the sums per direction
    (:func:`naive_sums`); the centroids use the unsaturated totals; with ``pass_fill``
    the later passes give back part of what they remove from each bin (``fill`` in
    :func:`naive_sums`).

    Returns
    -------
    ao : (n,) float64, and occlusion : (K, n) float64 of every pass.
    """
    lo, hi = surface.positions.min(0), surface.positions.max(0)
    scale = float((hi - lo).max())
    positions = (surface.positions - 0.5 * (lo + hi)) / scale
    areas = naive_vertex_areas(positions, surface.faces)
    points = positions + 1e-4 * np.sqrt(areas)[:, None] * surface.normals
    reach = None if max_distance is None else max_distance / scale
    radii = np.array([0.005, 0.02, 0.08, 0.32, 1.28, 5.12])  # aobake.constants.PASS_RADII
    weights = np.ones((len(positions), len(radii) + 1))
    occ = []
    occluders = None
    bins = np.zeros((len(positions), 2, 2 * max(sectors, 1)))
    for k in range(passes):
        first = np.zeros((len(positions), 3))
        plain = np.zeros((len(positions), 2))
        sums = naive_sums(
            positions,
            surface.normals,
            areas,
            surface.faces,
            points,
            weights,
            measure,
            reach,
            near,
            np.ones(len(positions)),
            radii,
            pass_reach,
            occluders,
            gate,
            first,
            sectors,
            plain,
            bins if k == 0 else None,
            bins if k > 0 and pass_fill else None,
        )
        if k == 0:
            total = plain[:, 0] + plain[:, 1]
            occluders = positions.copy()
            ok = total > 1e-9
            occluders[ok] = points[ok] + first[ok] / total[ok, None]
        a = np.clip(sums.max(axis=1) if sides == "max" else sums[:, 0], 0, 1)  # (n, bins)
        occ.append(a[:, -1])
        weights[:, 1:] = 1.0 - damping * a
    occ = np.array(occ)
    if combine == "last":
        ao = 1.0 - occ[-1]
    elif combine == "bunnell":
        ao = 1.0 - (0.4 * occ[-2] + 0.6 * occ[-1])
    else:
        a0, a1 = 1.0 - occ[-2], 1.0 - occ[-1]
        ao = 0.7 * np.minimum(a0, a1) + 0.3 * np.maximum(a0, a1)
    return ao, occ
