"""Per-texel fits of an AO field: the radial model of Omega by weighted least squares and
Levenberg-Marquardt, and the characteristic point C_o of the mean occluded direction.

Symbols follow Kontkanen & Laine: 1/Omega(r) = a r^2 + b r + c (or the cap model) and
Y(r) = normalize(C_o - x). Imports numpy, numba, aobake.constants and other kernels only.

References
----------
J. Kontkanen and S. Laine, "Ambient Occlusion Fields", I3D 2005.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .field_model import (
    N_PARAMS,
    OMEGA_MIN,
    P_A,
    P_B,
    P_C,
    P_CX,
    P_CY,
    P_CZ,
    P_R0,
    den_floor,
    model_omega,
    model_slope,
    omega_to_den,
)


@njit(cache=True, error_model="numpy", inline="always")
def _damped_step(h, g, mu, eps, kkt, rhs):
    """Levenberg-Marquardt step of a 3-parameter fit: solve ``(H + mu diag(H) + eps I)
    x = -g`` into ``rhs`` (``kkt``: scratch); False when singular."""
    for a in range(3):
        rhs[a] = -g[a]
        for b in range(3):
            kkt[a, b] = h[a, b]
        kkt[a, a] += mu * h[a, a] + eps
    return _solve_small(kkt, rhs, 3)


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy", inline="always")
def _den(beta, s):
    return beta[0] + s * (beta[1] + s * beta[2])


@njit(cache=True, error_model="numpy")
def _den_min(b0, b1, b2, slo, shi):
    """Smallest value of b0 + b1 s + b2 s^2 on [slo, shi] and where it is (scalars, so
    callers' C and strided arrays share one specialisation)."""
    s_best = slo
    d_best = b0 + slo * (b1 + slo * b2)
    d = b0 + shi * (b1 + shi * b2)
    if d < d_best:
        s_best, d_best = shi, d
    if b2 > 0.0:
        sv = -b1 / (2.0 * b2)
        if slo < sv < shi:
            d = b0 + sv * (b1 + sv * b2)
            if d < d_best:
                s_best, d_best = sv, d
    return s_best, d_best


@njit(cache=True, error_model="numpy")
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
            s_worst, d_worst = _den_min(beta[0], beta[1], beta[2], slo, 1.0)
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


@njit(cache=True, error_model="numpy", inline="always")
def _trial_step(h, g, mu, eps, kkt, rhs, x, trial):
    """A damped step from ``x`` into ``trial`` (:func:`_damped_step`); False when singular."""
    if not _damped_step(h, g, mu, eps, kkt, rhs):
        return False
    for a in range(3):
        trial[a] = x[a] + rhs[a]
    return True


@njit(cache=True, error_model="numpy", inline="always")
def _improves(new, cost, trial, x):
    """Levenberg-Marquardt's acceptance: ``trial`` replaces ``x`` when it lowers the cost."""
    if new < cost:
        for a in range(3):
            x[a] = trial[a]
        return True
    return False


@njit(cache=True, error_model="numpy")
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
            if not _trial_step(h, g, mu, 1e-15, work[2], work[3, :, 0], beta, trial):
                mu *= 10.0
                continue
            _, dmin = _den_min(trial[0], trial[1], trial[2], slo, 1.0)
            new = np.inf
            if dmin >= den_floor(model):
                new = 0.0
                for i in range(m):
                    if ok[i]:
                        new += q[i] * (om[i] - model_omega(_den(trial, s[i]), model)) ** 2
            if _improves(new, cost, trial, beta):
                cost = new
                mu *= 0.3
                accepted = True
                break
            mu *= 10.0
        if not accepted:
            break


@njit(cache=True, error_model="numpy", inline="always")
def _clamp_centre(c, dx, dy, dz, limit):
    """Project C onto the half-space C.w <= limit (w = the texel direction)."""
    excess = c[0] * dx + c[1] * dy + c[2] * dz - limit
    if excess > 0.0:
        c[0] -= excess * dx
        c[1] -= excess * dy
        c[2] -= excess * dz


@njit(cache=True, error_model="numpy")
def _centre_cost(c0, c1, c2, radii, unit, dx, dy, dz, wts, lam, tiny):
    """sum w_i |normalize(C - x_i) - Y_i|^2 + lam |C|^2 (C as scalars, so callers' C and
    strided arrays share one specialisation)."""
    c = (c0, c1, c2)
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


@njit(cache=True, error_model="numpy")
def _refine_centre(c, radii, unit, dx, dy, dz, wts, lam, limit, iters, work):
    """Projected Levenberg-Marquardt on :func:`_centre_cost` from ``c`` (in place);
    returns the final cost."""
    tiny = 1e-12 * radii[radii.shape[0] - 1]
    _clamp_centre(c, dx, dy, dz, limit)
    cost = _centre_cost(c[0], c[1], c[2], radii, unit, dx, dy, dz, wts, lam, tiny)
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
            if not _trial_step(h, g, mu, 1e-300, work[4], work[5, :, 0], c, trial):
                mu *= 10.0
                continue
            _clamp_centre(trial, dx, dy, dz, limit)
            new = _centre_cost(trial[0], trial[1], trial[2], radii, unit, dx, dy, dz, wts, lam, tiny)
            if _improves(new, cost, trial, c):
                cost = new
                mu *= 0.3
                accepted = True
                break
            mu *= 10.0
        if not accepted:
            break
    return cost


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy", nogil=True)
def fit_texels(radial, samples, dirs, r0, r_far, settings, out_params, out_resid):
    """Fit the 7 scalars of every texel to its radial samples. Serial and ``nogil``: the
    caller runs one call per worker thread, each on its own texels (a parallel loop
    here cost more to compile than it saved).

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
    for t in range(n_tex):
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
