"""Light sampling and path bookkeeping for the ray-traced irradiance reference.

Serial ``nogil`` kernels run one per worker thread on its own chunk of vertices
(:mod:`aobake.methods.embree.light` drives them around Embree). Every sample is a pure
function of (vertex key, component, sample index), so results do not depend on threads.

A light is one row of ``params`` (float64, see :data:`P_*`) and one code in ``kinds``
(:data:`KIND_CODES`); points are in the tracer's recentred frame (mesh units).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import rng, warps
from .rays import sobol_cosine_direction

KIND_CODES = {"distant": 0, "point": 1, "spot": 2, "sphere": 3, "rect": 4, "disk": 5, "dome": 6}
DISTANT, POINT, SPOT, SPHERE, RECT, DISK, DOME = range(7)

# Columns of a light's parameter row.
P_VALUE = 0  # 3: E_perp, I or L (RGB)
P_POS = 3  # 3: position (recentred)
P_DIR = 6  # 3: distant: towards the light; spot: the way it shines
P_U = 9  # 3: rect half-edge u
P_V = 12  # 3: rect half-edge v
P_NORMAL = 15  # 3: rect/disk emitting side
P_RADIUS = 18
P_COS_HALF = 19  # distant: cos(angle / 2)
P_COS_INNER = 20
P_COS_OUTER = 21
P_RANGE = 22
P_SHADOW = 23  # 1.0: casts shadow rays
P_AREA = 24
N_PARAMS = 25

# The ground plane's row (``plane``): up axis (-1: no plane), height (recentred mesh
# units), offset of a path's point on it (relative: eps x (magnitude + |point|)), albedo.
G_AXIS, G_HEIGHT, G_EPS, G_MAGNITUDE, G_ALBEDO = 0, 1, 2, 3, 4
G_SIZE = 7

# Why a receiver is not lit by a light (reach codes).
REACH_OK, REACH_BEHIND, REACH_CONE, REACH_RANGE, REACH_NONE = range(5)

# Component of an emitter sample: the last one after the lights.
_TWO_PI = 2.0 * math.pi


def light_table(lights, center: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(kinds (L,) int64, params (L, N_PARAMS) float64) of ``lights`` in the frame
    recentred on ``center`` (``lights``: :class:`aobake.shading.Light`s; a plain
    numpy function, the table the kernels here read)."""
    kinds = np.array([KIND_CODES[light.kind] for light in lights], dtype=np.int64)
    params = np.zeros((len(lights), N_PARAMS))
    for i, light in enumerate(lights):
        row = params[i]
        row[P_VALUE : P_VALUE + 3] = light.value
        row[P_POS : P_POS + 3] = light.position - center
        row[P_DIR : P_DIR + 3] = light.direction
        row[P_U : P_U + 3] = light.u
        row[P_V : P_V + 3] = light.v
        row[P_NORMAL : P_NORMAL + 3] = light.normal
        row[P_RADIUS] = light.radius
        row[P_COS_HALF] = math.cos(0.5 * light.angle)
        row[P_COS_INNER] = math.cos(light.cone_inner)
        row[P_COS_OUTER] = math.cos(light.cone_outer)
        row[P_RANGE] = light.range
        row[P_SHADOW] = 1.0 if light.shadow else 0.0
        row[P_AREA] = light.area
    return kinds, params


@njit(cache=True, error_model="numpy", inline="always")
def _dot(ax, ay, az, bx, by, bz):
    return ax * bx + ay * by + az * bz


@njit(cache=True, error_model="numpy", nogil=True)
def reach_code(kind, p, x, y, z, nx, ny, nz):
    """Whether the light row ``p`` can light a receiver at (x, y, z) with unit normal n:
    REACH_OK, else the first failing test of range, tangent plane (or emitting side),
    spot cone; REACH_NONE for a receiver without a normal. Same tests as
    :func:`aobake.plan.reach`."""
    if nx == 0.0 and ny == 0.0 and nz == 0.0:
        return REACH_NONE
    if kind == DOME:
        return REACH_OK
    if kind == DISTANT:
        sin_half = math.sqrt(max(0.0, 1.0 - p[P_COS_HALF] * p[P_COS_HALF]))
        if _dot(nx, ny, nz, p[P_DIR], p[P_DIR + 1], p[P_DIR + 2]) > -sin_half:
            return REACH_OK
        return REACH_BEHIND
    tx, ty, tz = p[P_POS] - x, p[P_POS + 1] - y, p[P_POS + 2] - z
    dist = math.sqrt(tx * tx + ty * ty + tz * tz)
    if not dist < p[P_RANGE]:
        return REACH_RANGE
    facing = _dot(nx, ny, nz, tx, ty, tz)
    if kind == POINT or kind == SPOT:
        if not facing > 0.0:
            return REACH_BEHIND
        if kind == SPOT:
            cos_axis = -_dot(tx, ty, tz, p[P_DIR], p[P_DIR + 1], p[P_DIR + 2]) / dist
            if not cos_axis > p[P_COS_OUTER]:
                return REACH_CONE
        return REACH_OK
    if kind == SPHERE:
        if facing > -p[P_RADIUS] and dist > p[P_RADIUS]:
            return REACH_OK
        return REACH_BEHIND
    mx, my, mz = p[P_NORMAL], p[P_NORMAL + 1], p[P_NORMAL + 2]
    if not -_dot(tx, ty, tz, mx, my, mz) > 0.0:
        return REACH_BEHIND
    if kind == RECT:
        for su in (-1.0, 1.0):
            for sv in (-1.0, 1.0):
                cx = tx + su * p[P_U] + sv * p[P_V]
                cy = ty + su * p[P_U + 1] + sv * p[P_V + 1]
                cz = tz + su * p[P_U + 2] + sv * p[P_V + 2]
                if _dot(nx, ny, nz, cx, cy, cz) > 0.0:
                    return REACH_OK
        return REACH_BEHIND
    # disk: its farthest point along n is the centre plus radius times n's in-plane part
    nm = _dot(nx, ny, nz, mx, my, mz)
    ix, iy, iz = nx - nm * mx, ny - nm * my, nz - nm * mz
    extent = p[P_RADIUS] * math.sqrt(ix * ix + iy * iy + iz * iz)
    if facing + extent > 0.0:
        return REACH_OK
    return REACH_BEHIND


@njit(cache=True, error_model="numpy", forceinline=True)
def _cone_direction(ax, ay, az, cos_max, u0, u1):
    """Uniform direction in the cone of half-angle acos(cos_max) about unit a."""
    c = 1.0 - u0 * (1.0 - cos_max)
    s = math.sqrt(max(0.0, 1.0 - c * c))
    phi = _TWO_PI * u1
    x, y = s * math.cos(phi), s * math.sin(phi)
    return warps.to_world(x, y, c, ax, ay, az)


@njit(cache=True, error_model="numpy", forceinline=True)
def sample_light(kind, p, i, ox, oy, oz, nx, ny, nz, u0, u1):
    """One sample of light ``i`` (row i of ``params`` ``p``: indexing the table, not
    a row view, saves a view's reference counting per sample) seen from o with unit
    normal n.

    Returns (wr, wg, wb, dx, dy, dz, dist): the irradiance estimate if the unit direction
    d is unoccluded up to ``dist`` (inf: to infinity); w = 0 when the sample adds
    nothing (behind the tangent plane or the light, outside the cone: no ray then).
    Inlined by LLVM (``forceinline``) into the loops that call it, as are the kinds' own
    functions: a call to any of them in the loop made a rect light's sample 20 ns instead
    of 8 (numba's own ``inline="always"`` is as fast but compiles ~20 s slower cold).
    """
    if kind == RECT:
        return _sample_rect(p, i, ox, oy, oz, nx, ny, nz, u0, u1)
    if kind == DISK:
        return _sample_disk(p, i, ox, oy, oz, nx, ny, nz, u0, u1)
    if kind == POINT or kind == SPOT:
        return _sample_point(p, i, kind == SPOT, ox, oy, oz, nx, ny, nz)
    if kind == SPHERE:
        return _sample_sphere(p, i, ox, oy, oz, nx, ny, nz, u0, u1)
    if kind == DISTANT:
        return _sample_distant(p, i, nx, ny, nz, u0, u1)
    return _sample_dome(p, i, nx, ny, nz, u0, u1)


@njit(cache=True, error_model="numpy", forceinline=True)
def _sample_distant(p, i, nx, ny, nz, u0, u1):
    """:func:`sample_light` of a distant light (a cone of directions when it has an angle)."""
    ax, ay, az = p[i, P_DIR], p[i, P_DIR + 1], p[i, P_DIR + 2]
    cos_half = p[i, P_COS_HALF]
    scale = 1.0
    if cos_half < 1.0:
        ax, ay, az = _cone_direction(ax, ay, az, cos_half, u0, u1)
        # uniform radiance over the cone: E_perp = L pi sin^2, pdf 1 / (2 pi (1 - cos))
        scale = 2.0 * (1.0 - cos_half) / (1.0 - cos_half * cos_half)
    c = _dot(nx, ny, nz, ax, ay, az)
    if not c > 0.0:
        return 0.0, 0.0, 0.0, ax, ay, az, np.inf
    f = c * scale
    return p[i, P_VALUE] * f, p[i, P_VALUE + 1] * f, p[i, P_VALUE + 2] * f, ax, ay, az, np.inf


@njit(cache=True, error_model="numpy", forceinline=True)
def _sample_point(p, i, spot, ox, oy, oz, nx, ny, nz):
    """:func:`sample_light` of a point light, or of a spot light (``spot``)."""
    tx, ty, tz = p[i, P_POS] - ox, p[i, P_POS + 1] - oy, p[i, P_POS + 2] - oz
    d2 = tx * tx + ty * ty + tz * tz
    d = math.sqrt(d2)
    if not d > 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0
    tx, ty, tz = tx / d, ty / d, tz / d
    c = _dot(nx, ny, nz, tx, ty, tz)
    if not c > 0.0:
        return 0.0, 0.0, 0.0, tx, ty, tz, d
    f = c / d2
    if spot:
        # glTF KHR_lights_punctual: squared linear ramp in cos between the cones
        cd = -_dot(tx, ty, tz, p[i, P_DIR], p[i, P_DIR + 1], p[i, P_DIR + 2])
        ramp = (cd - p[i, P_COS_OUTER]) / max(1e-3, p[i, P_COS_INNER] - p[i, P_COS_OUTER])
        ramp = min(1.0, max(0.0, ramp))
        f *= ramp * ramp
    return p[i, P_VALUE] * f, p[i, P_VALUE + 1] * f, p[i, P_VALUE + 2] * f, tx, ty, tz, d


@njit(cache=True, error_model="numpy", forceinline=True)
def _sample_sphere(p, i, ox, oy, oz, nx, ny, nz, u0, u1):
    """:func:`sample_light` of a sphere light: uniform in the cone it subtends."""
    tx, ty, tz = p[i, P_POS] - ox, p[i, P_POS + 1] - oy, p[i, P_POS + 2] - oz
    d2 = tx * tx + ty * ty + tz * tz
    r = p[i, P_RADIUS]
    if not d2 > r * r:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0
    d = math.sqrt(d2)
    cos_max = math.sqrt(max(0.0, 1.0 - r * r / d2))
    dx, dy, dz = _cone_direction(tx / d, ty / d, tz / d, cos_max, u0, u1)
    c = _dot(nx, ny, nz, dx, dy, dz)
    if not c > 0.0:
        return 0.0, 0.0, 0.0, dx, dy, dz, 0.0
    ct = _dot(dx, dy, dz, tx, ty, tz)  # d cos(theta)
    dist = ct - math.sqrt(max(0.0, r * r - (d2 - ct * ct)))
    f = c * _TWO_PI * (1.0 - cos_max)
    return p[i, P_VALUE] * f, p[i, P_VALUE + 1] * f, p[i, P_VALUE + 2] * f, dx, dy, dz, dist


@njit(cache=True, error_model="numpy", forceinline=True)
def _sample_rect(p, i, ox, oy, oz, nx, ny, nz, u0, u1):
    """:func:`sample_light` of a rect light: a uniform point of its area."""
    a, b = 2.0 * u0 - 1.0, 2.0 * u1 - 1.0
    qx = p[i, P_POS] + a * p[i, P_U] + b * p[i, P_V]
    qy = p[i, P_POS + 1] + a * p[i, P_U + 1] + b * p[i, P_V + 1]
    qz = p[i, P_POS + 2] + a * p[i, P_U + 2] + b * p[i, P_V + 2]
    return _from_area_point(p, i, qx, qy, qz, ox, oy, oz, nx, ny, nz)


@njit(cache=True, error_model="numpy", forceinline=True)
def _sample_disk(p, i, ox, oy, oz, nx, ny, nz, u0, u1):
    """:func:`sample_light` of a disk light: a uniform point of its area."""
    a, b = warps.square_to_uniform_disk_concentric(u0, u1)
    r = p[i, P_RADIUS]
    ex, ey, ez, fx, fy, fz = warps.frame(p[i, P_NORMAL], p[i, P_NORMAL + 1], p[i, P_NORMAL + 2])
    qx = p[i, P_POS] + r * (a * ex + b * fx)
    qy = p[i, P_POS + 1] + r * (a * ey + b * fy)
    qz = p[i, P_POS + 2] + r * (a * ez + b * fz)
    return _from_area_point(p, i, qx, qy, qz, ox, oy, oz, nx, ny, nz)


@njit(cache=True, error_model="numpy", forceinline=True)
def _from_area_point(p, i, qx, qy, qz, ox, oy, oz, nx, ny, nz):
    """The sample of a rect or disk light through its point q (area measure)."""
    tx, ty, tz = qx - ox, qy - oy, qz - oz
    d2 = tx * tx + ty * ty + tz * tz
    d = math.sqrt(d2)
    if not d > 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0
    tx, ty, tz = tx / d, ty / d, tz / d
    c = _dot(nx, ny, nz, tx, ty, tz)
    cl = -_dot(p[i, P_NORMAL], p[i, P_NORMAL + 1], p[i, P_NORMAL + 2], tx, ty, tz)
    if not (c > 0.0 and cl > 0.0):
        return 0.0, 0.0, 0.0, tx, ty, tz, d
    f = c * cl * p[i, P_AREA] / d2
    return p[i, P_VALUE] * f, p[i, P_VALUE + 1] * f, p[i, P_VALUE + 2] * f, tx, ty, tz, d


@njit(cache=True, error_model="numpy", forceinline=True)
def _sample_dome(p, i, nx, ny, nz, u0, u1):
    """:func:`sample_light` of a dome: a cosine-weighted direction that escapes sees pi L."""
    x, y, z = warps.square_to_cosine_hemisphere(u0, u1)
    dx, dy, dz = warps.to_world(x, y, z, nx, ny, nz)
    return p[i, P_VALUE] * math.pi, p[i, P_VALUE + 1] * math.pi, p[i, P_VALUE + 2] * math.pi, dx, dy, dz, np.inf


@njit(cache=True, error_model="numpy", forceinline=True)
def sample_emitter(ox, oy, oz, nx, ny, nz, u0, u1, pos, faces, tris, cdf, emission, lum_total, shorten):
    """One sample of the emitting triangles, chosen by area x emission (``cdf`` over
    ``tris``); a triangle emits on the side its winding's normal points to, as rect
    and disk lights do. Returns (wr, wg, wb, dx, dy, dz, dist), ``dist``
    shortened by the triangle's ``shorten`` so the emitter itself is not a blocker."""
    lo, hi = 0, cdf.shape[0] - 1
    while lo < hi:  # first entry with cdf > u0
        mid = (lo + hi) // 2
        if cdf[mid] > u0:
            hi = mid
        else:
            lo = mid + 1
    below = cdf[lo - 1] if lo > 0 else 0.0
    u0 = min(max((u0 - below) / max(cdf[lo] - below, 1e-300), 0.0), 1.0)
    t = tris[lo]
    su = math.sqrt(u0)
    b0, b1 = 1.0 - su, u1 * su
    b2 = 1.0 - b0 - b1
    i0, i1, i2 = faces[t, 0], faces[t, 1], faces[t, 2]
    qx = b0 * pos[i0, 0] + b1 * pos[i1, 0] + b2 * pos[i2, 0]
    qy = b0 * pos[i0, 1] + b1 * pos[i1, 1] + b2 * pos[i2, 1]
    qz = b0 * pos[i0, 2] + b1 * pos[i1, 2] + b2 * pos[i2, 2]
    ex, ey, ez = pos[i1, 0] - pos[i0, 0], pos[i1, 1] - pos[i0, 1], pos[i1, 2] - pos[i0, 2]
    fx, fy, fz = pos[i2, 0] - pos[i0, 0], pos[i2, 1] - pos[i0, 1], pos[i2, 2] - pos[i0, 2]
    gx, gy, gz = ey * fz - ez * fy, ez * fx - ex * fz, ex * fy - ey * fx
    g = math.sqrt(gx * gx + gy * gy + gz * gz)
    tx, ty, tz = qx - ox, qy - oy, qz - oz
    d2 = tx * tx + ty * ty + tz * tz
    d = math.sqrt(d2)
    if not (d > 0.0 and g > 0.0):
        return 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0
    tx, ty, tz = tx / d, ty / d, tz / d
    c = _dot(nx, ny, nz, tx, ty, tz)
    cl = -_dot(gx, gy, gz, tx, ty, tz) / g  # one-sided: the receiver in front of the face
    if not (c > 0.0 and cl > 0.0):
        return 0.0, 0.0, 0.0, tx, ty, tz, d
    er, eg, eb = emission[t, 0], emission[t, 1], emission[t, 2]
    # pdf per area = lum_t / lum_total, lum_t = er + eg + eb
    f = c * cl / d2 * lum_total / (er + eg + eb)
    return er * f, eg * f, eb * f, tx, ty, tz, max(0.0, d - shorten[t])


@njit(cache=True, error_model="numpy", nogil=True)
def component_keys(vertex_key, n_components):
    """Per-component scramble seeds (s0, s1) of one vertex."""
    out = np.zeros((n_components, 2), dtype=np.uint64)
    for c in range(n_components):
        s0, s1 = rng.scramble_seeds(rng.hash2(vertex_key, np.uint64(c)))
        out[c, 0] = s0
        out[c, 1] = s1
    return out


@njit(cache=True, error_model="numpy", nogil=True)
def direct_samples(
    vertex_index, points, origins, normals, keys, kinds, params, j_lo, j_hi, reach,
    pos, faces, tris, cdf, emission, lum_total, shorten, scale, far_cap, sums, squares,
    out_org, out_dir, out_far, out_w, out_row, out_comp,
):  # fmt: skip
    """Shadow rays of every light (and the emitters, component ``len(kinds)``) at the
    chunk's vertices, vertex-major, then light, then sample.

    ``points`` (n, 3) float64: the vertices (recentred), where the estimate is made;
    ``origins`` (n, 3) float32 in Embree's frame (``scale``: mesh units per frame unit);
    samples ``j_lo[c] .. j_hi[c] - 1`` of component c (none when equal); ``reach``
    (n, L) codes. A sample with w = 0 makes nothing; one of a light without shadows is
    added to ``sums[a, c]`` (and its square to ``squares``) at once; the others are
    written as rays (``out_far``: float32 lengths in Embree's frame, at most
    ``far_cap``) for :func:`add_samples`. Returns the number of rays written.
    """
    n_lights = kinds.shape[0]
    inv_scale = 1.0 / scale
    m = 0
    for a in range(vertex_index.shape[0]):
        v = vertex_index[a]
        nx, ny, nz = normals[v, 0], normals[v, 1], normals[v, 2]
        if nx == 0.0 and ny == 0.0 and nz == 0.0:
            continue
        # the estimate is made at the vertex; its shadow ray starts at the offset origin
        ox, oy, oz = points[v, 0], points[v, 1], points[v, 2]
        rx = np.float64(origins[v, 0]) * scale
        ry = np.float64(origins[v, 1]) * scale
        rz = np.float64(origins[v, 2]) * scale
        for c in range(n_lights + 1):
            if j_hi[c] <= j_lo[c]:
                continue
            if c < n_lights:
                if reach[v, c] != REACH_OK:
                    continue
                shadow = params[c, P_SHADOW] > 0.0
            else:
                shadow = True
            s0, s1 = rng.scramble_seeds(rng.hash2(keys[v], np.uint64(c)))
            for j in range(j_lo[c], j_hi[c]):
                u0, u1 = rng.scrambled_sobol2_fast(j, s0, s1)
                if c < n_lights:
                    wr, wg, wb, dx, dy, dz, dist = sample_light(kinds[c], params, c, ox, oy, oz, nx, ny, nz, u0, u1)
                else:
                    wr, wg, wb, dx, dy, dz, dist = sample_emitter(
                        ox, oy, oz, nx, ny, nz, u0, u1, pos, faces, tris, cdf, emission, lum_total, shorten
                    )
                if not (wr > 0.0 or wg > 0.0 or wb > 0.0):
                    continue
                if not shadow:
                    sums[a, c, 0] += wr
                    sums[a, c, 1] += wg
                    sums[a, c, 2] += wb
                    squares[a, c, 0] += wr * wr
                    squares[a, c, 1] += wg * wg
                    squares[a, c, 2] += wb * wb
                    continue
                if dist < np.inf:  # aim at the sampled point from the ray's origin
                    tx = ox + dist * dx - rx
                    ty = oy + dist * dy - ry
                    tz = oz + dist * dz - rz
                    dist = math.sqrt(tx * tx + ty * ty + tz * tz)
                    if not dist > 0.0:
                        continue
                    dx, dy, dz = tx / dist, ty / dist, tz / dist
                out_org[m, 0] = origins[v, 0]
                out_org[m, 1] = origins[v, 1]
                out_org[m, 2] = origins[v, 2]
                out_dir[m, 0] = dx
                out_dir[m, 1] = dy
                out_dir[m, 2] = dz
                out_far[m] = min(dist * inv_scale, far_cap)
                out_w[m, 0] = wr
                out_w[m, 1] = wg
                out_w[m, 2] = wb
                out_row[m] = a
                out_comp[m] = c
                m += 1
    return m


@njit(cache=True, error_model="numpy", nogil=True)
def add_samples(ids, w, row, comp, m, sums, squares):
    """Add unoccluded samples (``ids == -1``) to ``sums[row, comp]`` and their squares to
    ``squares[row, comp]``, in row order (the order they were made)."""
    for r in range(m):
        if ids[r] != -1:
            continue
        a, c = row[r], comp[r]
        for k in range(3):
            sums[a, c, k] += w[r, k]
            squares[a, c, k] += w[r, k] * w[r, k]


@njit(cache=True, error_model="numpy", nogil=True)
def path_hashes(p0, p1):
    """(p1 - p0,) uint64: the index half of the hash of a vertex's paths p0..p1-1
    (:func:`aobake.kernels.rng.index_hash`), shared by every vertex and depth."""
    out = np.empty(p1 - p0, dtype=np.uint64)
    for s in range(p1 - p0):
        out[s] = rng.index_hash(p0 + s)
    return out


@njit(cache=True, error_model="numpy", nogil=True)
def first_rays(vertices, per, p0, origins, normals, keys, alive, throughput, value_d, value_i, out_live, out_org, out_dir):
    """Start paths 0..len(vertices) * per - 1 (``per`` a vertex in order: path
    ``a * per + s`` is sample ``p0 + s`` of ``vertices[a]``) and write their first rays,
    compacted (``out_live[r]`` the path): from the vertex's offset origin, a scrambled
    Sobol cosine-weighted direction about its normal, the frame made once a vertex.
    Paths of a vertex without a normal are dead. Returns the number of rays.

    A vertex's local directions are made first in a loop with no branch, which LLVM
    vectorises (with AVX-512: ~11 ns a path against ~23 for the same values one at a
    time)."""
    lx, ly, lz = np.empty(per), np.empty(per), np.empty(per)
    m = 0
    for a in range(vertices.shape[0]):
        v = vertices[a]
        nx, ny, nz = normals[v, 0], normals[v, 1], normals[v, 2]
        has_normal = nx != 0.0 or ny != 0.0 or nz != 0.0
        for s in range(per):
            p = a * per + s
            alive[p] = has_normal
            for k in range(3):
                throughput[p, k] = 1.0
                value_d[p, k] = 0.0
                value_i[p, k] = 0.0
        if not has_normal:
            continue
        s0, s1 = rng.scramble_seeds(rng.hash2(keys[v], np.uint64(1000003)))
        for s in range(per):
            lx[s], ly[s], lz[s] = sobol_cosine_direction(p0 + s, s0, s1)
        tx, ty, tz, bx, by, bz = warps.frame(nx, ny, nz)
        ox, oy, oz = origins[v, 0], origins[v, 1], origins[v, 2]
        for s in range(per):
            x, y, z = lx[s], ly[s], lz[s]
            out_live[m] = a * per + s
            out_org[m, 0] = ox
            out_org[m, 1] = oy
            out_org[m, 2] = oz
            out_dir[m, 0] = x * tx + y * bx + z * nx
            out_dir[m, 1] = x * ty + y * by + z * ny
            out_dir[m, 2] = x * tz + y * bz + z * nz
            m += 1
    return m


@njit(cache=True, error_model="numpy", nogil=True)
def bounce_directions(path_org, path_normal, alive, keys, vertices, per, hashes, depth, inv_scale, out_live, out_org, out_dir):
    """Rays of the live paths after their first hit (``depth`` >= 1), compacted:
    ``out_live[r]`` the path, its origin (float32, Embree's frame) and a cosine-weighted
    direction about its normal. Paths are laid out as by :func:`first_rays`; ``hashes``
    (:func:`path_hashes`) is their index's. The first direction is a scrambled Sobol
    point; these are independent hashes: two Owen-scrambled copies of one sequence
    indexed alike are correlated, and a path multiplies them (measured: a bias of ~20%
    on the box's indirect light). Returns the number of rays."""
    m = 0
    for a in range(vertices.shape[0]):
        key = rng.hash2(keys[vertices[a]], np.uint64(1000003 + depth))
        for s in range(per):
            p = a * per + s
            if not alive[p]:
                continue
            u0, u1 = rng.random2_hashed(hashes[s], key)
            x, y, z = warps.square_to_cosine_hemisphere(u0, u1)
            dx, dy, dz = warps.to_world(x, y, z, path_normal[p, 0], path_normal[p, 1], path_normal[p, 2])
            out_live[m] = p
            out_org[m, 0] = path_org[p, 0] * inv_scale
            out_org[m, 1] = path_org[p, 1] * inv_scale
            out_org[m, 2] = path_org[p, 2] * inv_scale
            out_dir[m, 0] = dx
            out_dir[m, 1] = dy
            out_dir[m, 2] = dz
            m += 1
    return m


@njit(cache=True, error_model="numpy", nogil=True)
def follow_hits(
    live, m, prim, org, dirs, scale, points, faces, path_org, path_normal, throughput, value, alive,
    face_normals, face_albedo, dome, offset, continue_paths, on_plane, plane,
):  # fmt: skip
    """After tracing rays 0..m-1 of the live paths ``live`` (first hits ``prim``): an
    escaping path adds throughput x pi L_dome to ``value`` and ends; a hit moves the
    path to the hit point (the ray met with the face's plane in float64, offset along
    the face normal turned to face the ray), takes the face's albedo into the
    throughput and ends where that is zero or ``continue_paths`` is False.

    ``plane``: the ground plane's row (:data:`G_AXIS` ...; axis -1: none). A ray Embree
    missed with ``on_plane[r]`` set (:func:`ground_clip`) met the plane: the path moves
    onto it (offset up), faces up and takes the plane's albedo."""
    axis = int(plane[G_AXIS])
    height = plane[G_HEIGHT]
    for r in range(m):
        p = live[r]
        f = prim[r]
        if f < 0 and axis >= 0 and on_plane[r] != 0:
            if not continue_paths:
                alive[p] = False
                continue
            ox = np.float64(org[r, 0]) * scale
            oy = np.float64(org[r, 1]) * scale
            oz = np.float64(org[r, 2]) * scale
            dx, dy, dz = np.float64(dirs[r, 0]), np.float64(dirs[r, 1]), np.float64(dirs[r, 2])
            o_up = ox if axis == 0 else (oy if axis == 1 else oz)
            d_up = dx if axis == 0 else (dy if axis == 1 else dz)
            t = max(o_up - height, 0.0) / -d_up
            qx, qy, qz = ox + t * dx, oy + t * dy, oz + t * dz
            e = plane[G_EPS] * (plane[G_MAGNITUDE] + max(abs(qx), abs(qy), abs(qz)))
            path_org[p, 0] = qx
            path_org[p, 1] = qy
            path_org[p, 2] = qz
            path_org[p, axis] = height + e
            for k in range(3):
                path_normal[p, k] = 1.0 if k == axis else 0.0
            black = True
            for k in range(3):
                throughput[p, k] *= plane[G_ALBEDO + k]
                if throughput[p, k] > 0.0:
                    black = False
            if black:
                alive[p] = False
            continue
        if f < 0:
            for k in range(3):
                value[p, k] += throughput[p, k] * math.pi * dome[k]
            alive[p] = False
            continue
        gx, gy, gz = face_normals[f, 0], face_normals[f, 1], face_normals[f, 2]
        dx, dy, dz = np.float64(dirs[r, 0]), np.float64(dirs[r, 1]), np.float64(dirs[r, 2])
        along = _dot(gx, gy, gz, dx, dy, dz)
        if not continue_paths or along == 0.0:
            alive[p] = False
            continue
        ox = np.float64(org[r, 0]) * scale
        oy = np.float64(org[r, 1]) * scale
        oz = np.float64(org[r, 2]) * scale
        v0 = faces[f, 0]
        t = _dot(points[v0, 0] - ox, points[v0, 1] - oy, points[v0, 2] - oz, gx, gy, gz) / along
        if along > 0.0:
            gx, gy, gz = -gx, -gy, -gz
        t = max(t, 0.0)
        e = offset[f]
        path_org[p, 0] = ox + t * dx + e * gx
        path_org[p, 1] = oy + t * dy + e * gy
        path_org[p, 2] = oz + t * dz + e * gz
        path_normal[p, 0] = gx
        path_normal[p, 1] = gy
        path_normal[p, 2] = gz
        black = True
        for k in range(3):
            throughput[p, k] *= face_albedo[f, k]
            if throughput[p, k] > 0.0:
                black = False
        if black:
            alive[p] = False


@njit(cache=True, error_model="numpy", nogil=True)
def hit_samples(
    alive, path_org, path_normal, throughput, keys, vertices, per, hashes, depth,
    kinds, params, has_emitters, pos, faces, tris, cdf, emission, lum_total, shorten, inv_scale, far_cap,
    value, out_org, out_dir, out_far, out_w, out_row,
):  # fmt: skip
    """Next-event estimation at every live path's hit point: one sample per light (the
    dome excluded: escaping paths see it) and one of the emitters, weighted by the
    path's throughput. Paths are laid out as by :func:`first_rays`. A light without
    shadows adds to ``value`` at once; the others are written as rays as in
    :func:`direct_samples` (``out_row`` = path). Returns the number of rays."""
    n_lights = kinds.shape[0]
    m = 0
    comp_keys = np.zeros(n_lights + 1, dtype=np.uint64)
    # per component, once a call: sampled here (the dome with shadows and absent
    # emitters are not), has a finite range to test, casts shadow rays
    sampled = np.ones(n_lights + 1, dtype=np.bool_)
    ranged = np.zeros(n_lights + 1, dtype=np.bool_)
    shadows = np.ones(n_lights + 1, dtype=np.bool_)
    for c in range(n_lights):
        kind = kinds[c]
        sampled[c] = not (kind == DOME and params[c, P_SHADOW] > 0.0)
        ranged[c] = kind != DISTANT and kind != DOME and params[c, P_RANGE] < np.inf
        shadows[c] = params[c, P_SHADOW] > 0.0
    sampled[n_lights] = has_emitters
    for a in range(vertices.shape[0]):
        key = rng.hash2(keys[vertices[a]], np.uint64(2000003 + depth))
        for c in range(n_lights + 1):
            comp_keys[c] = rng.hash2(key, np.uint64(c))
        for s in range(per):
            p = a * per + s
            if not alive[p]:
                continue
            ox, oy, oz = path_org[p, 0], path_org[p, 1], path_org[p, 2]
            nx, ny, nz = path_normal[p, 0], path_normal[p, 1], path_normal[p, 2]
            for c in range(n_lights + 1):
                if not sampled[c]:
                    continue
                if ranged[c]:  # beyond the range: no sample (the other culling makes w = 0)
                    tx, ty, tz = params[c, P_POS] - ox, params[c, P_POS + 1] - oy, params[c, P_POS + 2] - oz
                    if not tx * tx + ty * ty + tz * tz < params[c, P_RANGE] * params[c, P_RANGE]:
                        continue
                u0, u1 = rng.random2_hashed(hashes[s], comp_keys[c])
                if c < n_lights:
                    wr, wg, wb, dx, dy, dz, dist = sample_light(kinds[c], params, c, ox, oy, oz, nx, ny, nz, u0, u1)
                else:
                    wr, wg, wb, dx, dy, dz, dist = sample_emitter(
                        ox, oy, oz, nx, ny, nz, u0, u1, pos, faces, tris, cdf, emission, lum_total, shorten
                    )
                wr *= throughput[p, 0]
                wg *= throughput[p, 1]
                wb *= throughput[p, 2]
                if not (wr > 0.0 or wg > 0.0 or wb > 0.0):
                    continue
                if not shadows[c]:
                    value[p, 0] += wr
                    value[p, 1] += wg
                    value[p, 2] += wb
                    continue
                out_org[m, 0] = ox * inv_scale
                out_org[m, 1] = oy * inv_scale
                out_org[m, 2] = oz * inv_scale
                out_dir[m, 0] = dx
                out_dir[m, 1] = dy
                out_dir[m, 2] = dz
                out_far[m] = min(dist * inv_scale, far_cap)
                out_w[m, 0] = wr
                out_w[m, 1] = wg
                out_w[m, 2] = wb
                out_row[m] = p
                m += 1
    return m


@njit(cache=True, error_model="numpy", nogil=True)
def add_path_samples(ids, w, row, m, value):
    """Add unoccluded next-event samples to their path's ``value``, in row order."""
    for r in range(m):
        if ids[r] != -1:
            continue
        p = row[r]
        for k in range(3):
            value[p, k] += w[r, k]


@njit(cache=True, error_model="numpy", nogil=True)
def path_sums(value_direct, value_indirect, per, sums_direct, sums_indirect, squares):
    """Per vertex of the chunk: the sums of its ``per`` consecutive paths' direct and
    indirect values and of the squares of their totals, in path order (in registers: a
    sum read and written back through the array every path took twice as long)."""
    for a in range(sums_direct.shape[0]):
        for k in range(3):
            sd, si, sq = sums_direct[a, k], sums_indirect[a, k], squares[a, k]
            for s in range(per):
                d, i = value_direct[a * per + s, k], value_indirect[a * per + s, k]
                sd += d
                si += i
                sq += (d + i) * (d + i)
            sums_direct[a, k], sums_indirect[a, k], squares[a, k] = sd, si, sq


@njit(cache=True, error_model="numpy", nogil=True)
def ground_clip(org, dirs, m, axis, height, far_cap, slack, far, on_plane):
    """Path rays 0..m-1 against the ground plane ``x[axis] = height`` (Embree's frame):
    where a ray going down meets it within ``far_cap`` (its origin clamped to the
    plane: one offset below it starts on it), ``on_plane[r]`` is 1 and ``far[r]`` that
    distance plus ``slack`` x (1 + distance), so Embree looks for nearer triangles only
    but still finds a modelled floor lying in the plane (it keeps its albedo); else
    ``far_cap``, 0."""
    for r in range(m):
        down = -np.float64(dirs[r, axis])
        far[r] = far_cap
        on_plane[r] = 0
        if down > 0.0:
            t = max(np.float64(org[r, axis]) - height, 0.0) / down
            if t < far_cap:
                far[r] = min(t + slack * (1.0 + t), far_cap)
                on_plane[r] = 1


@njit(cache=True, error_model="numpy", nogil=True)
def ground_shadows(org, dirs, far, m, axis, height, on_plane):
    """Shadow rays 0..m-1 (lengths ``far``, Embree's frame) that meet the ground plane
    before their end: ``on_plane[r]`` 1, the ray is occluded, and its origin moves to
    3 dir (outside the scene's box, going away: Embree rejects it at its root); else 0."""
    for r in range(m):
        down = -np.float64(dirs[r, axis])
        on_plane[r] = 0
        if down > 0.0 and max(np.float64(org[r, axis]) - height, 0.0) < np.float64(far[r]) * down:
            on_plane[r] = 1
            for k in range(3):
                org[r, k] = np.float32(3.0) * dirs[r, k]


@njit(cache=True, error_model="numpy", nogil=True)
def reach_all(points, normals, kinds, params):
    """(n, L) int8 reach codes (:func:`reach_code`) of every vertex and light."""
    n, n_lights = points.shape[0], kinds.shape[0]
    out = np.zeros((n, n_lights), dtype=np.int8)
    for i in range(n):
        for c in range(n_lights):
            out[i, c] = reach_code(
                kinds[c], params[c], points[i, 0], points[i, 1], points[i, 2], normals[i, 0], normals[i, 1], normals[i, 2]
            )
    return out
