"""Distances from a point inside a convex hull to its boundary, without building the hull:
support values and an exact simplex method over the vertices.

Imports numpy, numba and other kernels only.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from . import warps


@njit(cache=True, error_model="numpy", parallel=True)
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


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy")
def _bary(px, py, x, y):
    """Barycentric coordinates of (x, y) in the triangle (px, py)[:3]."""
    det = (px[1] - px[0]) * (py[2] - py[0]) - (px[2] - px[0]) * (py[1] - py[0])
    if det == 0.0:
        return 0.0, 0.0, 0.0, False
    l1 = ((x - px[0]) * (py[2] - py[0]) - (px[2] - px[0]) * (y - py[0])) / det
    l2 = ((px[1] - px[0]) * (y - py[0]) - (x - px[0]) * (py[1] - py[0])) / det
    return 1.0 - l1 - l2, l1, l2, True


@njit(cache=True, error_model="numpy")
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


# not parallel: a few ms per thousand directions, less than the parfor compile (~1 s)
@njit(cache=True, error_model="numpy")
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
    for q in range(dirs.shape[0]):
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
