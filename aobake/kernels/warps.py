"""Scalar warps from the unit square to directions, with their pdfs, and orthonormal frames.

Warps are pure functions of uniform numbers (pbrt-v4, mitsuba3 naming); frames follow
Duff et al., "Building an Orthonormal Basis, Revisited" (JCGT 2017): branch-free and
continuous except at n_z = -1's sign switch, exact for +-z.
"""

from __future__ import annotations

import math

from numba import njit

INV_PI = 1.0 / math.pi


@njit(cache=True, inline="always")
def sincos_quarter(x):
    """(sin x, cos x) for |x| <= pi/4 by Taylor polynomials of degree 11 and 12.

    Truncation error below 1e-12 on that interval (x^13/13! at pi/4), far below the
    float32 precision of ray directions, and a few times faster than libm's sin + cos.
    """
    x2 = x * x
    s = x * (
        1.0
        + x2
        * (
            -1.0 / 6.0
            + x2
            * (
                1.0 / 120.0
                + x2 * (-1.0 / 5040.0 + x2 * (1.0 / 362880.0 + x2 * (-1.0 / 39916800.0)))
            )
        )
    )
    c = 1.0 + x2 * (
        -0.5
        + x2
        * (
            1.0 / 24.0
            + x2
            * (
                -1.0 / 720.0
                + x2 * (1.0 / 40320.0 + x2 * (-1.0 / 3628800.0 + x2 * (1.0 / 479001600.0)))
            )
        )
    )
    return s, c


@njit(cache=True, inline="always")
def square_to_uniform_disk_concentric(u0, u1):
    """Shirley-Chiu concentric map: area-preserving, keeps strata compact.

    phi = (pi/4)(b/a) in the left/right wedges, pi/2 - (pi/4)(a/b) in the others, so
    only sin and cos on [-pi/4, pi/4] are needed (the second case swaps them).
    """
    a = 2.0 * u0 - 1.0
    b = 2.0 * u1 - 1.0
    if a == 0.0 and b == 0.0:
        return 0.0, 0.0
    if a * a > b * b:
        s, c = sincos_quarter((math.pi / 4.0) * (b / a))
        return a * c, a * s
    s, c = sincos_quarter((math.pi / 4.0) * (a / b))
    return b * s, b * c


@njit(cache=True, error_model="numpy", forceinline=True)
def concentric_selects(u0, u1):
    """:func:`square_to_uniform_disk_concentric` bit for bit, its wedge and zero cases
    chosen by selects instead of branches, so a loop of it vectorises (the division and
    the polynomial are made for both wedges alike)."""
    a = 2.0 * u0 - 1.0
    b = 2.0 * u1 - 1.0
    wide = a * a > b * b
    r = a if wide else b
    q = b if wide else a
    s, c = sincos_quarter((math.pi / 4.0) * (q / r))
    x = r * c if wide else r * s
    y = r * s if wide else r * c
    zero = (a == 0.0) & (b == 0.0)
    return (0.0 if zero else x), (0.0 if zero else y)


@njit(cache=True, inline="always")
def square_to_cosine_hemisphere(u0, u1):
    """Cosine-weighted direction about +z (Malley's method on the concentric disk)."""
    x, y = square_to_uniform_disk_concentric(u0, u1)
    z = math.sqrt(max(0.0, 1.0 - x * x - y * y))
    return x, y, z


@njit(cache=True, inline="always")
def cosine_hemisphere_pdf(z):
    """pdf of :func:`square_to_cosine_hemisphere` per steradian at cos(theta) = z."""
    return max(z, 0.0) * INV_PI


@njit(cache=True, inline="always")
def square_to_uniform_hemisphere(u0, u1):
    """Uniform direction on the hemisphere about +z."""
    z = u0
    r = math.sqrt(max(0.0, 1.0 - z * z))
    phi = 2.0 * math.pi * u1
    return r * math.cos(phi), r * math.sin(phi), z


@njit(cache=True, inline="always")
def uniform_hemisphere_pdf(z):
    """pdf of :func:`square_to_uniform_hemisphere` (1/2pi above the horizon)."""
    return 0.5 * INV_PI if z >= 0.0 else 0.0


@njit(cache=True, inline="always")
def square_to_uniform_sphere(u0, u1):
    """Uniform direction on the whole sphere."""
    z = 1.0 - 2.0 * u0
    r = math.sqrt(max(0.0, 1.0 - z * z))
    phi = 2.0 * math.pi * u1
    return r * math.cos(phi), r * math.sin(phi), z


@njit(cache=True, inline="always")
def uniform_sphere_pdf():
    """pdf of :func:`square_to_uniform_sphere` (1/4pi)."""
    return 0.25 * INV_PI


@njit(cache=True, inline="always")
def frame(nx, ny, nz):
    """Two unit tangents (t, b) with (t, b, n) right-handed and orthonormal, n unit."""
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    tx, ty, tz = 1.0 + sign * nx * nx * a, sign * b, -sign * nx
    bx, by, bz = b, sign + ny * ny * a, -ny
    return tx, ty, tz, bx, by, bz


@njit(cache=True, inline="always")
def to_world(x, y, z, nx, ny, nz):
    """Rotate local (x, y, z) about +z into the frame whose z axis is n."""
    tx, ty, tz, bx, by, bz = frame(nx, ny, nz)
    return (
        x * tx + y * bx + z * nx,
        x * ty + y * by + z * ny,
        x * tz + y * bz + z * nz,
    )
