"""Cube-map rasterizer: the occluder's triangles drawn into six faces around a point.

Binary coverage at texel centres; Omega = sum of covered texels' exact solid angles and
the occluded vector integral int V w dw = sum of covered texels' exact vector integrals
(tables from the wrapper). Imports numpy, numba and aobake.constants only.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: Cube faces as (major axis, sign, u axis, v axis), the same layout as kernels/field_eval.py.
FACE_AXIS = np.array([0, 0, 1, 1, 2, 2], dtype=np.int64)
FACE_SIGN = np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0])
FACE_U = np.array([1, 1, 2, 2, 0, 0], dtype=np.int64)
FACE_V = np.array([2, 2, 0, 0, 1, 1], dtype=np.int64)

_MAX_POLY = 8  # a triangle clipped by 4 planes has at most 7 corners


@njit(cache=True, error_model="numpy", inline="always")
def major_face(x, y, z):
    """Cube face index of direction (x, y, z); -1 for the zero vector."""
    ax, ay, az = abs(x), abs(y), abs(z)
    if ax >= ay and ax >= az:
        if ax == 0.0:
            return -1
        return 0 if x > 0.0 else 1
    if ay >= az:
        return 2 if y > 0.0 else 3
    return 4 if z > 0.0 else 5


@njit(cache=True, error_model="numpy")
def _fill_polygon(px, py, n, size, cover, face):
    """Mark texels of ``cover[face]`` whose centres lie in the convex polygon (px, py)[:n]
    (texel units: texel i spans [i, i + 1]); edges inclusive, so shared edges leave no gap."""
    area = 0.0
    xmin, xmax, ymin, ymax = px[0], px[0], py[0], py[0]
    for k in range(n):
        k1 = (k + 1) % n
        area += px[k] * py[k1] - px[k1] * py[k]
        xmin = min(xmin, px[k])
        xmax = max(xmax, px[k])
        ymin = min(ymin, py[k])
        ymax = max(ymax, py[k])
    if area == 0.0:
        return
    orient = 1.0 if area > 0.0 else -1.0
    i0 = max(0, int(np.ceil(xmin - 0.5)))
    i1 = min(size - 1, int(np.floor(xmax - 0.5)))
    j0 = max(0, int(np.ceil(ymin - 0.5)))
    j1 = min(size - 1, int(np.floor(ymax - 0.5)))
    for i in range(i0, i1 + 1):
        cx = i + 0.5
        for j in range(j0, j1 + 1):
            cy = j + 0.5
            inside = True
            for k in range(n):
                k1 = (k + 1) % n
                e = (px[k1] - px[k]) * (cy - py[k]) - (py[k1] - py[k]) * (cx - px[k])
                if e * orient < 0.0:
                    inside = False
                    break
            if inside:
                cover[face, i, j] = 1


@njit(cache=True, error_model="numpy")
def _clip_to_face(tri, face, ax, ay, az, bx, by, bz):
    """Clip triangle ``tri`` (3, 3) against the frustum of ``face``: the 4 planes
    w >= |u|, w >= |v| through the eye (w = sign * q[axis]). Returns the polygon in
    (ax, ay, az) and its corner count; (bx, by, bz) is scratch."""
    a, s, ua, va = FACE_AXIS[face], FACE_SIGN[face], FACE_U[face], FACE_V[face]
    n = 3
    for k in range(3):
        ax[k], ay[k], az[k] = tri[k, 0], tri[k, 1], tri[k, 2]
    for plane in range(4):
        axis = ua if plane < 2 else va
        sg = 1.0 if plane % 2 == 0 else -1.0
        m = 0
        for k in range(n):
            k1 = (k + 1) % n
            p0 = (ax[k], ay[k], az[k])
            p1 = (ax[k1], ay[k1], az[k1])
            d0 = s * p0[a] - sg * p0[axis]
            d1 = s * p1[a] - sg * p1[axis]
            if d0 >= 0.0:
                bx[m], by[m], bz[m] = p0[0], p0[1], p0[2]
                m += 1
            if (d0 >= 0.0) != (d1 >= 0.0):
                t = d0 / (d0 - d1)
                bx[m] = p0[0] + t * (p1[0] - p0[0])
                by[m] = p0[1] + t * (p1[1] - p0[1])
                bz[m] = p0[2] + t * (p1[2] - p0[2])
                m += 1
        n = m
        if n < 3:
            return 0
        for k in range(n):
            ax[k], ay[k], az[k] = bx[k], by[k], bz[k]
    return n


@njit(cache=True, error_model="numpy", inline="always")
def _project(x, y, z, half):
    """Face of (x, y, z) and its texel coordinates on that face (-1 for the zero vector)."""
    f = major_face(x, y, z)
    if f == 0 or f == 1:
        w = abs(x)
        return f, (y / w + 1.0) * half, (z / w + 1.0) * half
    if f == 2 or f == 3:
        w = abs(y)
        return f, (z / w + 1.0) * half, (x / w + 1.0) * half
    if f == 4 or f == 5:
        w = abs(z)
        return f, (x / w + 1.0) * half, (y / w + 1.0) * half
    return -1, 0.0, 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _fill_triangle(x0, y0, x1, y1, x2, y2, size, cover, face):
    """Mark texels of ``cover[face]`` whose centres lie in a triangle (texel units)."""
    xmin = min(x0, min(x1, x2))
    xmax = max(x0, max(x1, x2))
    ymin = min(y0, min(y1, y2))
    ymax = max(y0, max(y1, y2))
    i0 = max(0, int(np.ceil(xmin - 0.5)))
    i1 = min(size - 1, int(np.floor(xmax - 0.5)))
    if i0 > i1:
        return
    j0 = max(0, int(np.ceil(ymin - 0.5)))
    j1 = min(size - 1, int(np.floor(ymax - 0.5)))
    if j0 > j1:
        return
    area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    if area == 0.0:
        return
    o = 1.0 if area > 0.0 else -1.0
    for i in range(i0, i1 + 1):
        cx = i + 0.5
        for j in range(j0, j1 + 1):
            cy = j + 0.5
            e0 = ((x1 - x0) * (cy - y0) - (y1 - y0) * (cx - x0)) * o
            e1 = ((x2 - x1) * (cy - y1) - (y2 - y1) * (cx - x1)) * o
            e2 = ((x0 - x2) * (cy - y2) - (y0 - y2) * (cx - x2)) * o
            if e0 >= 0.0 and e1 >= 0.0 and e2 >= 0.0:
                cover[face, i, j] = 1


@njit(cache=True, error_model="numpy")
def _render_point(vertices, faces, p, size, vface, vuv, cover, poly):
    """Rasterize all triangles around point ``p`` (3,) into ``cover`` (6, S, S)."""
    half = 0.5 * size
    px0, py0, pz0 = p[0], p[1], p[2]
    for i in range(vertices.shape[0]):
        f, u, v = _project(vertices[i, 0] - px0, vertices[i, 1] - py0, vertices[i, 2] - pz0, half)
        vface[i] = f
        vuv[i, 0] = u
        vuv[i, 1] = v
    tri = poly[8:11, :3]
    px = poly[0]
    py = poly[1]
    ax, ay, az, bx, by, bz = poly[2], poly[3], poly[4], poly[5], poly[6], poly[7]
    for t in range(faces.shape[0]):
        i0, i1, i2 = faces[t, 0], faces[t, 1], faces[t, 2]
        f = vface[i0]
        if f >= 0 and vface[i1] == f and vface[i2] == f:
            # all corners in one face's frustum (a convex cone): project the corners
            _fill_triangle(vuv[i0, 0], vuv[i0, 1], vuv[i1, 0], vuv[i1, 1], vuv[i2, 0], vuv[i2, 1], size, cover, f)
            continue
        for k in range(3):
            v = faces[t, k]
            tri[k, 0] = vertices[v, 0] - px0
            tri[k, 1] = vertices[v, 1] - py0
            tri[k, 2] = vertices[v, 2] - pz0
        for face in range(6):
            n = _clip_to_face(tri, face, ax, ay, az, bx, by, bz)
            if n < 3:
                continue
            m = np.int64(0)  # not a literal 0: typing would compile _fill_polygon for it too
            a, sg, ua, va = FACE_AXIS[face], FACE_SIGN[face], FACE_U[face], FACE_V[face]
            for k in range(n):
                q = (ax[k], ay[k], az[k])
                w = sg * q[a]
                if w > 0.0:  # w = 0 only at the eye itself
                    px[m] = (q[ua] / w + 1.0) * half
                    py[m] = (q[va] / w + 1.0) * half
                    m += 1
            if m >= 3:
                _fill_polygon(px, py, m, size, cover, face)


@njit(cache=True, error_model="numpy", nogil=True)
def render_points(vertices, faces, points, texel_weights, texel_vectors, out):
    """Omega and int V w dw at every point by cube-map rasterization. Serial and
    ``nogil``: the caller runs one call per worker thread, each on its own points (a
    parallel loop here cost more to compile than it saved).

    Parameters
    ----------
    vertices : (nv, 3) float64
    faces : (m, 3) int64
    points : (n, 3) float64
        Sample points, in the same frame as ``vertices``.
    texel_weights : (6, S, S) float64
        Exact solid angle of each texel.
    texel_vectors : (6, S, S, 3) float64
        Exact int_texel w dw of each texel.
    out : (n, 4) float64
        Written in full: Omega, then the occluded vector integral (x, y, z).
    """
    size = texel_weights.shape[1]
    n = points.shape[0]
    nv = vertices.shape[0]
    cover = np.zeros((6, size, size), dtype=np.uint8)
    vface = np.zeros(nv, dtype=np.int64)
    vuv = np.zeros((nv, 2))
    poly = np.zeros((11, _MAX_POLY))
    for p in range(n):
        cover[:] = 0
        _render_point(vertices, faces, points[p], size, vface, vuv, cover, poly)
        om = 0.0
        sx = 0.0
        sy = 0.0
        sz = 0.0
        for f in range(6):
            for i in range(size):
                for j in range(size):
                    if cover[f, i, j]:
                        om += texel_weights[f, i, j]
                        sx += texel_vectors[f, i, j, 0]
                        sy += texel_vectors[f, i, j, 1]
                        sz += texel_vectors[f, i, j, 2]
        out[p, 0] = om
        out[p, 1] = sx
        out[p, 2] = sy
        out[p, 3] = sz
