"""The cosine-weighted occlusion of a spherical cap, C(Omega, cos theta): closed form and
table lookup (the last step of evaluating an AO field).

Imports numba and aobake.constants only.

References
----------
J. Snyder, "Area Light Sources for Real-Time Graphics", Microsoft Research TR-96-11 (1996).
"""

from __future__ import annotations

import math

from numba import njit, prange

INV_PI = 1.0 / math.pi
FOUR_PI = 4.0 * math.pi


@njit(cache=True, error_model="numpy", inline="always")
def _cap_upper(cs, ct):
    """1/pi int_cap max(0, n.w) dw for a cap with cos(half-angle) ``cs`` in [0, 1] whose
    axis makes cos(theta) = ``ct`` with n (Snyder's closed form, sigma <= pi/2)."""
    s2 = 1.0 - cs * cs  # sin^2 sigma
    ss = math.sqrt(max(s2, 0.0))
    if ct >= ss:  # whole cap above the horizon (theta <= pi/2 - sigma)
        return s2 * ct
    if ct <= -ss:  # whole cap below (theta >= pi/2 + sigma)
        return 0.0
    # straddling: |ct| < sin(sigma), so sin(theta) > cos(sigma) >= 0 and sin(sigma) > 0
    st = math.sqrt(max(1.0 - ct * ct, 0.0))
    x = cs / ss  # cot sigma >= 0
    y = -x * ct / st
    y = min(1.0, max(-1.0, y))
    q = math.sqrt(max(1.0 - y * y, 0.0))
    # atan2 keeps the x = 0 limit (sigma = pi/2) finite: atan(+inf) = pi/2
    val = (ct * math.acos(y) - x * st * q) * s2 + math.atan2(st * q, x)
    return min(max(val * INV_PI, 0.0), 1.0)


@njit(cache=True, error_model="numpy", inline="always")
def cap_occlusion(omega, ct):
    """Cosine-weighted occlusion A of a spherical cap of solid angle ``omega`` whose axis
    makes cos(theta) = ``ct`` with the normal: C(Omega, cos theta) in [0, 1].

    cos(sigma) = 1 - Omega / 2pi. Caps larger than a hemisphere use the complement,
    C(sigma, theta) = 1 - C(pi - sigma, pi - theta) (normalised form of pi - I).
    """
    if not omega > 0.0:  # also catches NaN
        return 0.0
    ct = min(1.0, max(-1.0, ct))
    cs = 1.0 - omega * (0.5 * INV_PI)
    if cs <= -1.0:
        return 1.0
    if cs >= 0.0:
        return _cap_upper(cs, ct)
    return 1.0 - _cap_upper(-cs, -ct)


@njit(cache=True, error_model="numpy", parallel=True)
def cap_occlusion_array(omega, cos_theta, out):
    """out[i] = cap_occlusion(omega[i], cos_theta[i]) for (n,) float64 arrays."""
    for i in prange(omega.shape[0]):
        out[i] = cap_occlusion(omega[i], cos_theta[i])


@njit(cache=True, error_model="numpy", inline="always")
def cap_lookup(lut, omega, ct):
    """Bilinear lookup of C(Omega, cos theta) in ``lut`` (n_o + 1, n_c + 1), sampled at
    Omega = 4 pi i / n_o and cos theta = -1 + 2 j / n_c (built from the closed form)."""
    no = lut.shape[0] - 1
    nc = lut.shape[1] - 1
    x = min(max(omega * (no / FOUR_PI), 0.0), no - 1e-9)
    y = min(max((ct + 1.0) * (0.5 * nc), 0.0), nc - 1e-9)
    i = int(x)
    j = int(y)
    fx = x - i
    fy = y - j
    lo = lut[i, j] + fy * (lut[i, j + 1] - lut[i, j])
    hi = lut[i + 1, j] + fy * (lut[i + 1, j + 1] - lut[i + 1, j])
    return lo + fx * (hi - lo)
