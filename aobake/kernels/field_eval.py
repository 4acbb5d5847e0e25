"""Evaluation of AO fields at receivers: bilinear texel lookup, the radial model at the
receiver's distance from the hull, the cap integral, the hull blend and the far fade.

Imports numba, aobake.constants and other kernels only.

References
----------
J. Kontkanen and S. Laine, "Ambient Occlusion Fields", I3D 2005.
"""

from __future__ import annotations

import math

from numba import njit, prange

from .cap import cap_lookup
from .field_model import (
    MODEL_TABLE,
    P_A,
    P_B,
    P_C,
    P_CX,
    P_CY,
    P_CZ,
    P_R0,
    P_WX,
    P_WY,
    P_WZ,
    model_omega,
)
from .raster import FACE_AXIS, FACE_U, FACE_V, major_face


@njit(cache=True, error_model="numpy", inline="always")
def _texel_omega(texels, f, i, j, d, model):
    """Omega~ and unit Y~ of texel (f, i, j) (padded indices) at distance d >= 0 from
    the hull, r_c = r0 + d along the texel's own direction w (columns P_WX..):
    Y~ = normalize(C_o - r_c w)."""
    r0 = texels[f, i, j, P_R0]
    rc = r0 + d
    den = (texels[f, i, j, P_A] * rc + texels[f, i, j, P_B]) * rc + texels[f, i, j, P_C]
    om = model_omega(den, model)
    wx, wy, wz = texels[f, i, j, P_WX], texels[f, i, j, P_WY], texels[f, i, j, P_WZ]
    yx = texels[f, i, j, P_CX] - rc * wx
    yy = texels[f, i, j, P_CY] - rc * wy
    yz = texels[f, i, j, P_CZ] - rc * wz
    ln2 = yx * yx + yy * yy + yz * yz
    if ln2 > 0.0:
        inv = 1.0 / math.sqrt(ln2)
        return om, yx * inv, yy * inv, yz * inv, r0
    return om, -wx, -wy, -wz, r0


@njit(cache=True, error_model="numpy", inline="always")
def field_occlusion(texels, table, lut, config, x, y, z, nx, ny, nz):
    """Occlusion A in [0, 1] of one field at a receiver (x, y, z) with normal n, both
    in the field's frame (centre at the origin). ``config`` = (r_far, r_near, A0, p,
    model, d_min, knots per log-distance unit).

    Bilinear over the four nearest texels of the padded cube map, then the cap integral
    C(Omega, n.Y) from ``lut`` (:func:`~aobake.kernels.cap.cap_lookup`); inside the hull
    blended towards A0 with t = (r / r0)^p; faded to 0 from r_near to r_far
    (smoothstep). Returns -1 at or beyond r_far (skipped). Every texel is evaluated at
    the receiver's distance from the hull, d = max(r - r0, 0) with r0 interpolated
    bilinearly, i.e. at r0_k + d along its own ray: near a hull edge the four texels' r0
    differ a lot, and evaluating them all at the same r would mix points at very
    different distances from the surface. Analytic models blend Omega linearly and Y as
    the Omega-weighted mean; the table model interpolates each texel's knots linearly in
    log d and blends Omega and the vector integrals linearly."""
    r_far, r_near, a0, power = config[0], config[1], config[2], config[3]
    model = int(config[4])
    r = math.sqrt(x * x + y * y + z * z)
    if r >= r_far:
        return -1.0
    if r > 0.0:
        ox, oy, oz = x / r, y / r, z / r
    else:
        ox, oy, oz = 0.0, 0.0, 1.0
    f = major_face(ox, oy, oz)
    o = (ox, oy, oz)
    w = abs(o[FACE_AXIS[f]])
    res = texels.shape[1] - 2
    su = (o[FACE_U[f]] / w + 1.0) * (0.5 * res) - 0.5
    sv = (o[FACE_V[f]] / w + 1.0) * (0.5 * res) - 0.5
    su = min(max(su, -0.5), res - 0.5)
    sv = min(max(sv, -0.5), res - 0.5)
    iu = int(math.floor(su))
    iv = int(math.floor(sv))
    fu = su - iu
    fv = sv - iv
    w00 = (1.0 - fu) * (1.0 - fv)
    w10 = fu * (1.0 - fv)
    w01 = (1.0 - fu) * fv
    w11 = fu * fv
    i0, j0 = iu + 1, iv + 1
    r0 = (
        w00 * texels[f, i0, j0, P_R0]
        + w10 * texels[f, i0 + 1, j0, P_R0]
        + w01 * texels[f, i0, j0 + 1, P_R0]
        + w11 * texels[f, i0 + 1, j0 + 1, P_R0]
    )
    om = 0.0
    yx = 0.0
    yy = 0.0
    yz = 0.0
    if model == MODEL_TABLE:
        d_min, per_log = config[5], config[6]
        n_knots = table.shape[3]
        s = math.log(max(r - r0, d_min) / d_min) * per_log
        s = min(s, n_knots - 1.0)
        k0 = min(int(s), n_knots - 2)
        g = s - k0
        for k in range(4):
            ti = i0 + (k & 1)
            tj = j0 + (k >> 1)
            wk = w00 if k == 0 else (w10 if k == 1 else (w01 if k == 2 else w11))
            wa = wk * (1.0 - g)
            wb = wk * g
            om += wa * table[f, ti, tj, k0, 0] + wb * table[f, ti, tj, k0 + 1, 0]
            yx += wa * table[f, ti, tj, k0, 1] + wb * table[f, ti, tj, k0 + 1, 1]
            yy += wa * table[f, ti, tj, k0, 2] + wb * table[f, ti, tj, k0 + 1, 2]
            yz += wa * table[f, ti, tj, k0, 3] + wb * table[f, ti, tj, k0 + 1, 3]
    else:
        for k in range(4):
            wk = w00 if k == 0 else (w10 if k == 1 else (w01 if k == 2 else w11))
            o_k, y0, y1, y2, _ = _texel_omega(texels, f, i0 + (k & 1), j0 + (k >> 1), max(r - r0, 0.0), model)
            om += wk * o_k
            yx += wk * o_k * y0
            yy += wk * o_k * y1
            yz += wk * o_k * y2
    ln = math.sqrt(yx * yx + yy * yy + yz * yz)
    a = 0.0
    if ln > 0.0 and om > 0.0:
        a = cap_lookup(lut, om, (nx * yx + ny * yy + nz * yz) / ln)
    if r < r0:
        t = (r / r0) ** power
        a = t * a + (1.0 - t) * a0
    if r > r_near:
        u = (r_far - r) / (r_far - r_near)
        a *= u * u * (3.0 - 2.0 * u)
    return min(max(a, 0.0), 1.0)


@njit(cache=True, error_model="numpy", parallel=True)
def evaluate(arrays, config, frame, positions, normals, ao, skipped):
    """Multiply ``ao`` by 1 - A of one field at every receiver (1 - A = prod (1 - A_k)).

    Parameters
    ----------
    arrays : tuple
        ``texels`` (6, R + 2, R + 2, 10) float32, the padded cube map of the 7 scalars
        and the texel directions (P_WX..P_WZ); ``table`` (6, R + 2, R + 2, K, 4)
        float32, the table model's knots (Omega, int V w dw), any shape for other
        models; ``lut`` (n_o + 1, n_c + 1) float32, the cap integral (:func:`cap_lookup`).
    config : (7,) float64
        r_far, r_near, A0, p, radial model, d_min, knots per unit of log distance.
    frame : (4, 3) float64
        World to field frame: x_field = frame[:3] @ x + frame[3]; normals use frame[:3].
    positions, normals : (n, 3) float64
        Receivers in world space (normals unit, or zero for "no normal").
    ao : (n,) float64
        Multiplied in place by 1 - A.
    skipped : (n,) uint8
        Set to 1 where the receiver is at or beyond r_far (ao left unchanged).
    """
    texels, table, lut = arrays
    for i in prange(positions.shape[0]):
        px, py, pz = positions[i, 0], positions[i, 1], positions[i, 2]
        nx0, ny0, nz0 = normals[i, 0], normals[i, 1], normals[i, 2]
        x = frame[0, 0] * px + frame[0, 1] * py + frame[0, 2] * pz + frame[3, 0]
        y = frame[1, 0] * px + frame[1, 1] * py + frame[1, 2] * pz + frame[3, 1]
        z = frame[2, 0] * px + frame[2, 1] * py + frame[2, 2] * pz + frame[3, 2]
        nx = frame[0, 0] * nx0 + frame[0, 1] * ny0 + frame[0, 2] * nz0
        ny = frame[1, 0] * nx0 + frame[1, 1] * ny0 + frame[1, 2] * nz0
        nz = frame[2, 0] * nx0 + frame[2, 1] * ny0 + frame[2, 2] * nz0
        a = field_occlusion(texels, table, lut, config, x, y, z, nx, ny, nz)
        if a < 0.0:
            skipped[i] = 1
        else:
            ao[i] *= 1.0 - a
