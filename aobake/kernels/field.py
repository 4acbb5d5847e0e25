"""Compiled loops of ambient occlusion fields: cap integral, hull distances, fits, evaluation.

Symbols follow DESIGN.md section 4: a texel's model is 1/Omega(r) = a r^2 + b r + c and
Y(r) = normalize(C_o - x); r0 is the distance from the centre to the convex hull.
Imports numpy, numba, aobake.constants and other kernels only.

References
----------
J. Kontkanen and S. Laine, "Ambient Occlusion Fields", I3D 2005.
J. Snyder, "Area Light Sources for Real-Time Graphics", Microsoft Research TR-96-11 (1996).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..constants import FASTMATH
from . import rng, warps
from .raster import FACE_AXIS, FACE_U, FACE_V, major_face

INV_PI = 1.0 / math.pi
TWO_PI = 2.0 * math.pi
FOUR_PI = 4.0 * math.pi

#: Column of each scalar in a texel row (the 7 scalars of Kontkanen & Laine).
P_A, P_B, P_C, P_R0, P_CX, P_CY, P_CZ = 0, 1, 2, 3, 4, 5, 6
N_PARAMS = 7
#: Evaluation rows append the texel's unit direction (computed once by the wrapper).
P_WX, P_WY, P_WZ = 7, 8, 9
N_EVAL = 10


# ---------------------------------------------------------------------------------------
# cosine-weighted spherical cap


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
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


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
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


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", parallel=True)
def cap_occlusion_array(omega, cos_theta, out):
    """out[i] = cap_occlusion(omega[i], cos_theta[i]) for (n,) float64 arrays."""
    for i in prange(omega.shape[0]):
        out[i] = cap_occlusion(omega[i], cos_theta[i])


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
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


# ---------------------------------------------------------------------------------------
# convex-hull distances through the support function


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", parallel=True)
def support_values(vertices, normals, out_h, out_arg):
    """h(m) = max_v m.v and its argmax for every row m of ``normals`` (k, 3)."""
    for k in prange(normals.shape[0]):
        mx, my, mz = normals[k, 0], normals[k, 1], normals[k, 2]
        best = -np.inf
        arg = 0
        for v in range(vertices.shape[0]):
            d = mx * vertices[v, 0] + my * vertices[v, 1] + mz * vertices[v, 2]
            if d > best:
                best = d
                arg = v
        out_h[k] = best
        out_arg[k] = arg


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def _lifted(vertices, v, wx, wy, wz, t1, t2, big, low):
    """Vertex v (or artificial point -1..-3) as (b_x, b_y, a): its components across and
    along w. The artificial points are a big triangle around the axis, very low in a."""
    if v < 0:
        ang = (-1 - v) * (2.0 * math.pi / 3.0) + 0.5 * math.pi
        return big * math.cos(ang), big * math.sin(ang), low
    x, y, z = vertices[v, 0], vertices[v, 1], vertices[v, 2]
    return (
        x * t1[0] + y * t1[1] + z * t1[2],
        x * t2[0] + y * t2[1] + z * t2[2],
        x * wx + y * wy + z * wz,
    )


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _bary(px, py, x, y):
    """Barycentric coordinates of (x, y) in the triangle (px, py)[:3]."""
    det = (px[1] - px[0]) * (py[2] - py[0]) - (px[2] - px[0]) * (py[1] - py[0])
    if det == 0.0:
        return 0.0, 0.0, 0.0, False
    l1 = ((x - px[0]) * (py[2] - py[0]) - (px[2] - px[0]) * (y - py[0])) / det
    l2 = ((px[1] - px[0]) * (y - py[0]) - (x - px[0]) * (py[1] - py[0])) / det
    return 1.0 - l1 - l2, l1, l2, True


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _hull_simplex(vertices, pool, w, t1, t2, big, low, tol, basis, lam, max_iter):
    """Simplex method for max t s.t. t w = sum lam_v v, sum lam_v = 1, lam >= 0 over the
    vertices ``pool``, starting from the feasible ``basis`` (3 vertex indices, negative =
    artificial) with weights ``lam``; both updated in place. Returns True at optimum.

    The basis is a triangle of projected vertices containing the axis; the entering
    vertex is the one highest above the plane through the basis (the largest reduced
    cost), the leaving one comes from the ratio test."""
    wx, wy, wz = w[0], w[1], w[2]
    px = np.zeros(3)
    py = np.zeros(3)
    pa = np.zeros(3)
    for _ in range(max_iter):
        for k in range(3):
            px[k], py[k], pa[k] = _lifted(vertices, basis[k], wx, wy, wz, t1, t2, big, low)
        # plane a = t + gx bx + gy by through the three lifted points
        det = (px[1] - px[0]) * (py[2] - py[0]) - (px[2] - px[0]) * (py[1] - py[0])
        if det == 0.0:
            return False
        gx = ((pa[1] - pa[0]) * (py[2] - py[0]) - (pa[2] - pa[0]) * (py[1] - py[0])) / det
        gy = ((px[1] - px[0]) * (pa[2] - pa[0]) - (px[2] - px[0]) * (pa[1] - pa[0])) / det
        t = pa[0] - gx * px[0] - gy * py[0]
        best = tol
        enter = -1
        for q in range(pool.shape[0]):
            v = pool[q]
            bx, by, av = _lifted(vertices, v, wx, wy, wz, t1, t2, big, low)
            d = av - t - gx * bx - gy * by
            if d > best:
                best = d
                enter = v
        if enter < 0:
            return True
        bx, by, _ = _lifted(vertices, enter, wx, wy, wz, t1, t2, big, low)
        m0, m1, m2, ok = _bary(px, py, bx, by)
        if not ok:
            return False
        mu = (m0, m1, m2)
        leave = -1
        theta = np.inf
        for k in range(3):
            if mu[k] > 1e-15:
                ratio = lam[k] / mu[k]
                if ratio < theta:
                    theta = ratio
                    leave = k
        if leave < 0:
            return False
        for k in range(3):
            lam[k] = max(0.0, lam[k] - theta * mu[k])
        lam[leave] = theta
        basis[leave] = enter
    return False


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", parallel=True)
def hull_distances(dirs, candidates, vertices, out):
    """Distance r0 from the origin along each unit row of ``dirs`` to the boundary of the
    convex hull of ``vertices``: max t such that t w lies in conv(vertices).

    That is a linear program in the barycentric weights (3 equality rows), solved
    exactly by the simplex method: first over ``candidates`` (indices of likely hull
    vertices, e.g. support points), then verified and continued over all vertices, so
    the answer is the exact hull distance whatever the candidates. A big-M triangle of
    artificial points gives the first feasible basis. The origin must lie inside the
    hull; where it does not (or the simplex does not finish), r0 = 0.
    """
    nv = vertices.shape[0]
    scale = 0.0
    for v in range(nv):
        for k in range(3):
            scale = max(scale, abs(vertices[v, k]))
    big = 8.0 * scale + 1.0
    low = -1e6 * (scale + 1.0)
    tol = 1e-12 * (scale + 1e-300)
    every = np.arange(nv)
    for q in prange(dirs.shape[0]):
        w = dirs[q]
        t1x, t1y, t1z, t2x, t2y, t2z = warps.frame(w[0], w[1], w[2])
        t1 = (t1x, t1y, t1z)
        t2 = (t2x, t2y, t2z)
        basis = np.array([-1, -2, -3], dtype=np.int64)
        lam = np.full(3, 1.0 / 3.0)
        done = _hull_simplex(vertices, candidates, w, t1, t2, big, low, tol, basis, lam, 500)
        done = _hull_simplex(vertices, every, w, t1, t2, big, low, tol, basis, lam, 500)
        value = 0.0
        feasible = True
        for k in range(3):
            _, _, a = _lifted(vertices, basis[k], w[0], w[1], w[2], t1, t2, big, low)
            if basis[k] < 0 and lam[k] > 1e-9:
                feasible = False
            value += lam[k] * a
        out[q] = max(0.0, value) if (done and feasible) else 0.0


# ---------------------------------------------------------------------------------------
# Embree sampler: rays over the whole sphere from points spread over texel footprints


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", nogil=True)
def footprint_rays(geometry, keys, point_index, per, out_org, out_dir):
    """Fill ``per`` rays of every point in ``point_index``, point-major.

    ``geometry`` = (anchors (n, 3), tangents (n, 6), radii (n,), shift (3,)): ray j of
    point p starts at shift + radii[p] * unit(anchors[p] + (s0 - 1/2) t_u + (s1 - 1/2) t_v)
    with (t_u, t_v) = tangents[p] and (s0, s1) an Owen-scrambled Sobol point (a box
    prefilter over the texel footprint; zero tangents give a fixed point), and goes in a
    uniform direction on the sphere from a second, independently scrambled Sobol
    sequence. keys (n,) uint64; out_org / out_dir (k * per, 3) float32, written in full.
    """
    anchors, tangents, radii, shift = geometry
    for a in range(point_index.shape[0]):
        p = point_index[a]
        key = keys[p]
        key2 = rng.hash2(key, np.uint64(0x5EED))
        for j in range(per):
            u0, u1 = rng.scrambled_sobol2(j, key)
            dx, dy, dz = warps.square_to_uniform_sphere(u0, u1)
            s0, s1 = rng.scrambled_sobol2(j, key2)
            s0 -= 0.5
            s1 -= 0.5
            qx = anchors[p, 0] + s0 * tangents[p, 0] + s1 * tangents[p, 3]
            qy = anchors[p, 1] + s0 * tangents[p, 1] + s1 * tangents[p, 4]
            qz = anchors[p, 2] + s0 * tangents[p, 2] + s1 * tangents[p, 5]
            length = math.sqrt(qx * qx + qy * qy + qz * qz)
            scale = radii[p] / length if length > 0.0 else 0.0
            r = a * per + j
            out_org[r, 0] = shift[0] + scale * qx
            out_org[r, 1] = shift[1] + scale * qy
            out_org[r, 2] = shift[2] + scale * qz
            out_dir[r, 0] = dx
            out_dir[r, 1] = dy
            out_dir[r, 2] = dz


@njit(cache=True, nogil=True)
def accumulate_hits(ids, dirs, per, point_index, out):
    """out[p] += (hits, sum of hit directions) over the ``per`` rays of each point.

    Each point appears once per call with all its rays, summed in ray order, so the
    result does not depend on how points are split into chunks or threads.
    """
    for a in range(point_index.shape[0]):
        p = point_index[a]
        h = 0.0
        sx = 0.0
        sy = 0.0
        sz = 0.0
        for j in range(per):
            r = a * per + j
            if ids[r] != -1:
                h += 1.0
                sx += dirs[r, 0]
                sy += dirs[r, 1]
                sz += dirs[r, 2]
        out[p, 0] += h
        out[p, 1] += sx
        out[p, 2] += sy
        out[p, 3] += sz


# ---------------------------------------------------------------------------------------
# per-texel fits

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


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def model_omega(den, model):
    """Omega of a denominator value; 0 for den <= 0 (an empty texel has a = b = c = 0)."""
    if not den > 0.0:
        return 0.0
    if model == MODEL_PAPER:
        return min(1.0 / den, FOUR_PI)
    x = max(1.0 - 1.0 / den, 0.0)
    return TWO_PI * (1.0 - math.sqrt(x))


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def model_slope(den, model):
    """-dOmega/dden (>= 0) at ``den``."""
    if model == MODEL_PAPER:
        return 1.0 / (den * den)
    return math.pi / (den * den * max(math.sqrt(max(1.0 - 1.0 / den, 0.0)), _COS_FLOOR))


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def omega_to_den(om, model):
    """The denominator a sample's Omega (> 0) asks for."""
    if model == MODEL_PAPER:
        return 1.0 / om
    c = 1.0 - om / TWO_PI
    s2 = min(max(1.0 - c * c, 1e-300), 1.0)
    return 1.0 / s2


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def den_floor(model):
    """Smallest denominator the fit may reach on [r0, r_far]: Omega <= 4 pi (paper),
    Omega <= 2 pi (cap; outside the hull the occluder fits in a half-space)."""
    return 1.0 / FOUR_PI if model == MODEL_PAPER else 0.5

#: Samples with Omega at or below this (steradians) see no occluder and are dropped.
OMEGA_MIN = 1e-9


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def _damped_step(h, g, mu, eps, kkt, rhs):
    """Levenberg-Marquardt step of a 3-parameter fit: solve ``(H + mu diag(H) + eps I)
    x = -g`` into ``rhs`` (``kkt``: scratch); False when singular."""
    for a in range(3):
        rhs[a] = -g[a]
        for b in range(3):
            kkt[a, b] = h[a, b]
        kkt[a, a] += mu * h[a, a] + eps
    return _solve_small(kkt, rhs, 3)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _solve_small(m, b, n):
    """Solve m[:n, :n] x = b[:n] in place (Gaussian elimination, partial pivoting).

    The solution overwrites b[:n]. Returns False (b unusable) if a pivot vanishes."""
    scale = 0.0
    for i in range(n):
        for j in range(n):
            scale = max(scale, abs(m[i, j]))
    if not scale > 0.0:
        return False
    for col in range(n):
        piv = col
        best = abs(m[col, col])
        for r in range(col + 1, n):
            if abs(m[r, col]) > best:
                best = abs(m[r, col])
                piv = r
        if not best > 1e-14 * scale:
            return False
        if piv != col:
            for j in range(n):
                tmp = m[col, j]
                m[col, j] = m[piv, j]
                m[piv, j] = tmp
            tmp = b[col]
            b[col] = b[piv]
            b[piv] = tmp
        for r in range(col + 1, n):
            f = m[r, col] / m[col, col]
            for j in range(col, n):
                m[r, j] -= f * m[col, j]
            b[r] -= f * b[col]
    for col in range(n - 1, -1, -1):
        acc = b[col]
        for j in range(col + 1, n):
            acc -= m[col, j] * b[j]
        b[col] = acc / m[col, col]
    return True


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def _den(beta, s):
    return beta[0] + s * (beta[1] + s * beta[2])


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _den_min(beta, slo, shi):
    """Smallest value of beta0 + beta1 s + beta2 s^2 on [slo, shi] and where it is."""
    s_best = slo
    d_best = _den(beta, slo)
    d = _den(beta, shi)
    if d < d_best:
        s_best, d_best = shi, d
    if beta[2] > 0.0:
        sv = -beta[1] / (2.0 * beta[2])
        if slo < sv < shi:
            d = _den(beta, sv)
            if d < d_best:
                s_best, d_best = sv, d
    return s_best, d_best


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _fit_denominator(s, om, ok, slo, npar, beta, work, model):
    """Weighted LLS of den(Omega_i) ~ beta0 + beta1 s + beta2 s^2 (first ``npar``
    terms), weights (dOmega/dden)^2 (the error in Omega; (Omega / max)^4 for the paper's
    model), with den >= den_floor on [slo, 1] enforced by equality constraints at the
    worst points (active set, at most 2), else a constant."""
    m = s.shape[0]
    w_max = 0.0
    for i in range(m):
        if ok[i]:
            w_max = max(w_max, model_slope(omega_to_den(om[i], model), model))
    h = work[0]
    q = work[1, :, 0]
    kkt = work[2]
    rhs = work[3, :, 0]
    h[:, :] = 0.0
    q[:] = 0.0
    for i in range(m):
        if not ok[i]:
            continue
        y = omega_to_den(om[i], model)
        w = (model_slope(y, model) / w_max) ** 2
        phi0, phi1, phi2 = 1.0, s[i], s[i] * s[i]
        for a in range(npar):
            pa = phi0 if a == 0 else (phi1 if a == 1 else phi2)
            q[a] += w * pa * y
            for b in range(npar):
                pb = phi0 if b == 0 else (phi1 if b == 1 else phi2)
                h[a, b] += w * pa * pb
    trace = 0.0
    for a in range(npar):
        trace += h[a, a]
    cons = np.zeros(2)
    n_cons = 0
    floor = den_floor(model)
    target = floor * (1.0 + 1e-6)
    for _ in range(3):
        size = npar + n_cons
        kkt[:, :] = 0.0
        rhs[:] = 0.0
        for a in range(npar):
            rhs[a] = q[a]
            for b in range(npar):
                kkt[a, b] = h[a, b]
            kkt[a, a] += 1e-12 * trace
        for c in range(n_cons):
            sc = cons[c]
            for a in range(npar):
                pa = 1.0 if a == 0 else (sc if a == 1 else sc * sc)
                kkt[npar + c, a] = pa
                kkt[a, npar + c] = pa
            rhs[npar + c] = target
        solved = _solve_small(kkt, rhs, size)
        beta[:] = 0.0
        if solved:
            for a in range(npar):
                beta[a] = rhs[a]
            s_worst, d_worst = _den_min(beta, slo, 1.0)
            if d_worst >= floor and np.isfinite(d_worst):
                return
            if n_cons < 2 and n_cons < npar - 1:
                cons[n_cons] = s_worst
                n_cons += 1
                continue
        break
    # fallback: the constant that best fits 1/Omega with the same weights
    beta[:] = 0.0
    beta[0] = max(q[0] / h[0, 0], target)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _refine_omega(s, om, ok, q, slo, beta, iters, work, model):
    """Levenberg-Marquardt on sum q_i (Omega_i - Omega~(s_i))^2 (the paper's error in
    Omega, with quadrature weights q), keeping den >= den_floor on [slo, 1]; steps that
    do not lower the error are rejected."""
    m = s.shape[0]
    h = work[0]
    g = work[1, :, 0]
    trial = work[4, :, 0]
    cost = 0.0
    for i in range(m):
        if ok[i]:
            cost += q[i] * (om[i] - model_omega(_den(beta, s[i]), model)) ** 2
    mu = 1e-3
    for _ in range(iters):
        h[:, :] = 0.0
        g[:] = 0.0
        for i in range(m):
            if not ok[i]:
                continue
            d = _den(beta, s[i])
            e = om[i] - model_omega(d, model)
            sl = model_slope(d, model)
            phi = (sl, s[i] * sl, s[i] * s[i] * sl)  # dOmega~/dbeta = -phi: residual Jacobian +phi
            for a in range(3):
                g[a] += q[i] * phi[a] * e
                for b in range(3):
                    h[a, b] += q[i] * phi[a] * phi[b]
        accepted = False
        for _try in range(6):
            rhs = work[3, :, 0]
            if not _damped_step(h, g, mu, 1e-15, work[2], rhs):
                mu *= 10.0
                continue
            for a in range(3):
                trial[a] = beta[a] + rhs[a]
            _, dmin = _den_min(trial, slo, 1.0)
            new = np.inf
            if dmin >= den_floor(model):
                new = 0.0
                for i in range(m):
                    if ok[i]:
                        new += q[i] * (om[i] - model_omega(_den(trial, s[i]), model)) ** 2
            if new < cost:
                cost = new
                for a in range(3):
                    beta[a] = trial[a]
                mu *= 0.3
                accepted = True
                break
            mu *= 10.0
        if not accepted:
            break


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def _clamp_centre(c, dx, dy, dz, limit):
    """Project C onto the half-space C.w <= limit (w = the texel direction)."""
    excess = c[0] * dx + c[1] * dy + c[2] * dz - limit
    if excess > 0.0:
        c[0] -= excess * dx
        c[1] -= excess * dy
        c[2] -= excess * dz


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _centre_cost(c, radii, unit, dx, dy, dz, wts, lam, tiny):
    """sum w_i |normalize(C - x_i) - Y_i|^2 + lam |C|^2."""
    e = lam * (c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
    for i in range(radii.shape[0]):
        if wts[i] <= 0.0:
            continue
        ux = c[0] - radii[i] * dx
        uy = c[1] - radii[i] * dy
        uz = c[2] - radii[i] * dz
        ln = math.sqrt(ux * ux + uy * uy + uz * uz)
        if ln > tiny:
            ux /= ln
            uy /= ln
            uz /= ln
        e += wts[i] * ((ux - unit[i, 0]) ** 2 + (uy - unit[i, 1]) ** 2 + (uz - unit[i, 2]) ** 2)
    return e


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _refine_centre(c, radii, unit, dx, dy, dz, wts, lam, limit, iters, work):
    """Projected Levenberg-Marquardt on :func:`_centre_cost` from ``c`` (in place);
    returns the final cost."""
    tiny = 1e-12 * radii[radii.shape[0] - 1]
    _clamp_centre(c, dx, dy, dz, limit)
    cost = _centre_cost(c, radii, unit, dx, dy, dz, wts, lam, tiny)
    mu = 1e-3
    h = work[2]
    g = work[3, :, 0]
    trial = work[5, :, 1]
    for _ in range(iters):
        for p in range(3):
            g[p] = lam * c[p]
            for q in range(3):
                h[p, q] = lam if p == q else 0.0
        for i in range(radii.shape[0]):
            w = wts[i]
            if w <= 0.0:
                continue
            ux = c[0] - radii[i] * dx
            uy = c[1] - radii[i] * dy
            uz = c[2] - radii[i] * dz
            ln = math.sqrt(ux * ux + uy * uy + uz * uz)
            if ln <= tiny:
                continue
            u = (ux / ln, uy / ln, uz / ln)
            r = (u[0] - unit[i, 0], u[1] - unit[i, 1], u[2] - unit[i, 2])
            # J = (I - u u^T) / ln is symmetric: J^T J = (I - u u^T) / ln^2, J^T r
            ur = u[0] * r[0] + u[1] * r[1] + u[2] * r[2]
            for p in range(3):
                g[p] += w * (r[p] - u[p] * ur) / ln
                for q in range(3):
                    h[p, q] += w * ((1.0 if p == q else 0.0) - u[p] * u[q]) / (ln * ln)
        accepted = False
        for _try in range(6):
            rhs = work[5, :, 0]
            if not _damped_step(h, g, mu, 1e-300, work[4], rhs):
                mu *= 10.0
                continue
            for p in range(3):
                trial[p] = c[p] + rhs[p]
            _clamp_centre(trial, dx, dy, dz, limit)
            new = _centre_cost(trial, radii, unit, dx, dy, dz, wts, lam, tiny)
            if new < cost:
                cost = new
                for p in range(3):
                    c[p] = trial[p]
                mu *= 0.3
                accepted = True
                break
            mu *= 10.0
        if not accepted:
            break
    return cost


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _fit_centre(radii, unit, dx, dy, dz, wts, limit, iters, c_out, work):
    """C_o for one texel (see :func:`fit_texels`); ``limit`` bounds C.w (the hull
    distance), so Y~ seen from any point outside the hull points into it."""
    m = radii.shape[0]
    a = work[0]
    b = work[1, :, 0]
    a[:, :] = 0.0
    b[:] = 0.0
    total = 0.0
    for i in range(m):
        w = wts[i]
        if w <= 0.0:
            continue
        total += w
        y = (unit[i, 0], unit[i, 1], unit[i, 2])
        x = (radii[i] * dx, radii[i] * dy, radii[i] * dz)
        for p in range(3):
            for q in range(3):
                proj = (1.0 if p == q else 0.0) - y[p] * y[q]
                a[p, q] += w * proj
                b[p] += w * proj * x[q]
    c_out[0] = 0.0
    c_out[1] = 0.0
    c_out[2] = 0.0
    if total <= 0.0:
        return
    ridge = 1e-6 * (a[0, 0] + a[1, 1] + a[2, 2])
    for p in range(3):
        a[p, p] += ridge
    # the same ridge stays in the objective: when every Y_i is parallel to the texel's
    # ray, any C on that line fits and Gauss-Newton would drift along it
    lam = 1e-6 * total / (radii[m - 1] * radii[m - 1])
    c0 = np.zeros(3)
    cost0 = np.inf
    if _solve_small(a, b, 3):
        c0[0], c0[1], c0[2] = b[0], b[1], b[2]
        cost0 = _refine_centre(c0, radii, unit, dx, dy, dz, wts, lam, limit, iters, work)
    # second start at the centre: a flipped sample (C beyond it on its ray) is a saddle
    # the local steps cannot leave, so keep whichever start ends lower
    cost1 = _refine_centre(c_out, radii, unit, dx, dy, dz, wts, lam, limit, iters, work)
    if cost0 < cost1:
        c_out[0], c_out[1], c_out[2] = c0[0], c0[1], c0[2]


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", parallel=True)
def fit_texels(radial, samples, dirs, r0, r_far, settings, out_params, out_resid):
    """Fit the 7 scalars of every texel to its radial samples.

    Parameters
    ----------
    radial : (T, M, 2) float64
        Sample distances from the centre (increasing, within [r0, r_far]) and their
        quadrature weights q (the share of space each sample stands for).
    samples : (T, M, 4) float64
        Omega and the occluded vector integral int V w dw at each sample.
    dirs : (T, 3) float64
        Unit texel directions.
    r0 : (T,) float64
        Hull distance of each texel (the positivity constraint holds on [r0, r_far]).
    r_far : float
    settings : (4,) float64
        Levenberg-Marquardt iterations for Omega (0 = linear fit only) and for C_o, the
        power k of the Y weights q_i (Omega_i / max)^k, and the radial model
        (MODEL_PAPER or MODEL_CAP).
    out_params : (T, 7) float64
        a, b, c, r0, C_o (written in full); an empty texel (no sample sees the occluder)
        gets a = b = c = 0, which evaluation reads as Omega = 0.
    out_resid : (T, 2) float64
        RMS error over the valid samples, with the fits' weights, of Omega (sr) and of
        Y (degrees).
    """
    n_tex, m = radial.shape[0], radial.shape[1]
    iters_om = int(settings[0])
    iters_c = int(settings[1])
    y_power = settings[2]
    model = int(settings[3])
    for t in prange(n_tex):
        work = np.zeros((6, 4, 4))
        ok = np.zeros(m, dtype=np.bool_)
        s = np.zeros(m)
        om = np.zeros(m)
        unit = np.zeros((m, 3))
        wts = np.zeros(m)
        beta = np.zeros(3)
        centre = np.zeros(3)
        radii = np.zeros(m)
        q = np.zeros(m)
        n_ok = 0
        om_max = 0.0
        for i in range(m):
            radii[i] = radial[t, i, 0]
            q[i] = radial[t, i, 1]
            s[i] = radii[i] / r_far
            om[i] = samples[t, i, 0]
            if om[i] > OMEGA_MIN and q[i] > 0.0:  # q = 0: a knot beyond r_far
                ok[i] = True
                n_ok += 1
                om_max = max(om_max, om[i])
        for k in range(N_PARAMS):
            out_params[t, k] = 0.0
        out_params[t, P_R0] = r0[t]
        out_resid[t, 0] = 0.0
        out_resid[t, 1] = 0.0
        if n_ok == 0:
            continue
        slo = min(r0[t] / r_far, 1.0)
        _fit_denominator(s, om, ok, slo, min(n_ok, 3), beta, work, model)
        if iters_om > 0 and n_ok >= 3:
            _refine_omega(s, om, ok, q, slo, beta, iters_om, work, model)
        out_params[t, P_A] = beta[2] / (r_far * r_far)
        out_params[t, P_B] = beta[1] / r_far
        out_params[t, P_C] = beta[0]
        # mean occluded directions: weights q (Omega / max)^k (k = 2: the scale of their
        # AO effect)
        for i in range(m):
            vx, vy, vz = samples[t, i, 1], samples[t, i, 2], samples[t, i, 3]
            ln = math.sqrt(vx * vx + vy * vy + vz * vz)
            if ok[i] and ln > 1e-12 * om[i]:
                unit[i, 0] = vx / ln
                unit[i, 1] = vy / ln
                unit[i, 2] = vz / ln
                wts[i] = q[i] * (om[i] / om_max) ** y_power
        _fit_centre(radii, unit, dirs[t, 0], dirs[t, 1], dirs[t, 2], wts, r0[t], iters_c, centre, work)
        out_params[t, P_CX] = centre[0]
        out_params[t, P_CY] = centre[1]
        out_params[t, P_CZ] = centre[2]
        # residuals weighted like the fits: Omega by q (sr), Y by q (Omega / max)^k (far
        # samples see a speck whose mean direction does not matter for AO)
        e_om = 0.0
        q_sum = 0.0
        e_y = 0.0
        w_y = 0.0
        for i in range(m):
            if not ok[i]:
                continue
            e_om += q[i] * (om[i] - model_omega(_den(beta, s[i]), model)) ** 2
            q_sum += q[i]
            if wts[i] > 0.0:
                ux = centre[0] - radii[i] * dirs[t, 0]
                uy = centre[1] - radii[i] * dirs[t, 1]
                uz = centre[2] - radii[i] * dirs[t, 2]
                ln = math.sqrt(ux * ux + uy * uy + uz * uz)
                cosang = 1.0
                if ln > 0.0:
                    cosang = (ux * unit[i, 0] + uy * unit[i, 1] + uz * unit[i, 2]) / ln
                ang = math.acos(min(1.0, max(-1.0, cosang)))
                e_y += wts[i] * ang * ang
                w_y += wts[i]
        out_resid[t, 0] = math.sqrt(e_om / q_sum) if q_sum > 0.0 else 0.0
        out_resid[t, 1] = math.degrees(math.sqrt(e_y / w_y)) if w_y > 0.0 else 0.0


# ---------------------------------------------------------------------------------------
# evaluation


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
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


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", inline="always")
def field_occlusion(texels, table, lut, config, x, y, z, nx, ny, nz):
    """Occlusion A in [0, 1] of one field at a receiver (x, y, z) with normal n, both
    in the field's frame (centre at the origin). ``config`` = (r_far, r_near, A0, p,
    model, d_min, knots per log-distance unit).

    Bilinear over the four nearest texels of the padded cube map, then the cap integral
    C(Omega, n.Y) from ``lut`` (:func:`cap_lookup`); inside the hull blended towards A0 with t = (r / r0)^p; faded to 0
    from r_near to r_far (smoothstep). Returns -1 at or beyond r_far (skipped).
    Every texel is evaluated at the receiver's distance from the hull, d = max(r - r0,
    0) with r0 interpolated bilinearly, i.e. at r0_k + d along its own ray: near a hull
    edge the four texels' r0 differ a lot, and evaluating them all at the same r would
    mix points at very different distances from the surface (measured on the bench:
    RMSE 0.0111 vs 0.0122). Analytic models blend Omega linearly and Y as the
    Omega-weighted mean; the table model interpolates each texel's knots linearly in
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


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", parallel=True)
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
