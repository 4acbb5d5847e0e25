"""What an AO field texel holds and how its radial model gives Omega: the row layout of
the 7 scalars and the models of the denominator den(r) = a r^2 + b r + c.

Shared by the fit (``field_fit``) and the evaluation (``field_eval``). Imports numba and
aobake.constants only.

References
----------
J. Kontkanen and S. Laine, "Ambient Occlusion Fields", I3D 2005.
"""

from __future__ import annotations

import math

from numba import njit

TWO_PI = 2.0 * math.pi
FOUR_PI = 4.0 * math.pi

#: Column of each scalar in a texel row (the 7 scalars of Kontkanen & Laine).
P_A, P_B, P_C, P_R0, P_CX, P_CY, P_CZ = 0, 1, 2, 3, 4, 5, 6
N_PARAMS = 7
#: Evaluation rows append the texel's unit direction (computed once by the wrapper).
P_WX, P_WY, P_WZ = 7, 8, 9
N_EVAL = 10

#: Radial models of Omega in the denominator den(r) = a r^2 + b r + c (file "model"):
#: MODEL_PAPER: Omega = 1/den (Kontkanen & Laine); MODEL_CAP: den = 1/sin^2(sigma) of the
#: cap with the same solid angle, Omega = 2 pi (1 - sqrt(1 - 1/den)), exact for a sphere
#: and for a disk seen along its axis.
MODEL_PAPER = 0
MODEL_CAP = 1
#: MODEL_TABLE: the texels hold a MODEL_CAP fit, but evaluation interpolates the samples
#: themselves (Omega and int V w dw at every radial knot), linearly in log(r - r0).
MODEL_TABLE = 2
#: Cosine floor in the cap model's slope dOmega/dden, which is infinite at Omega = 2 pi.
_COS_FLOOR = 0.05


@njit(cache=True, error_model="numpy", inline="always")
def model_omega(den, model):
    """Omega of a denominator value; 0 for den <= 0 (an empty texel has a = b = c = 0)."""
    if not den > 0.0:
        return 0.0
    if model == MODEL_PAPER:
        return min(1.0 / den, FOUR_PI)
    x = max(1.0 - 1.0 / den, 0.0)
    return TWO_PI * (1.0 - math.sqrt(x))


@njit(cache=True, error_model="numpy", inline="always")
def model_slope(den, model):
    """-dOmega/dden (>= 0) at ``den``."""
    if model == MODEL_PAPER:
        return 1.0 / (den * den)
    return math.pi / (den * den * max(math.sqrt(max(1.0 - 1.0 / den, 0.0)), _COS_FLOOR))


@njit(cache=True, error_model="numpy", inline="always")
def omega_to_den(om, model):
    """The denominator a sample's Omega (> 0) asks for."""
    if model == MODEL_PAPER:
        return 1.0 / om
    c = 1.0 - om / TWO_PI
    s2 = min(max(1.0 - c * c, 1e-300), 1.0)
    return 1.0 / s2


@njit(cache=True, error_model="numpy", inline="always")
def den_floor(model):
    """Smallest denominator the fit may reach on [r0, r_far]: Omega <= 4 pi (paper),
    Omega <= 2 pi (cap; outside the hull the occluder fits in a half-space)."""
    return 1.0 / FOUR_PI if model == MODEL_PAPER else 0.5

#: Samples with Omega at or below this (steradians) see no occluder and are dropped.
OMEGA_MIN = 1e-9
