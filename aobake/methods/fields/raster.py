"""Solid angle and mean occluded direction at points, by rasterizing cube maps on the CPU.

The sampler of Kontkanen & Laine (2005), section 4.1, without a GPU: around each point
the occluder's triangles are drawn into the six faces of a cube map (binary coverage at
texel centres). Omega is the sum of the covered texels' exact solid angles (texels near
a face's corner subtend less), and the occluded vector integral int V w dw the sum of
their exact vector integrals. Numpy-facing wrapper of ``aobake.kernels.raster`` (``_k.*``).

References
----------
J. Arvo, "Applications of Irradiance Tensors to the Simulation of Non-Lambertian
Phenomena", SIGGRAPH 1995 (exact vector integral of a spherical polygon).
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np

from ..._types import FloatArray
from ...checks import numba_threads
from ...errors import NumericalError
from ...kernels import raster as _k
from ...progress import NullProgress, Progress
from ...tracing import split, trace_chunks
from .layout import face_directions
from .options import FieldOptions

# Points per kernel call (one task of a worker thread): scratch buffers are allocated
# once per call; small enough that the threads' shares even out.
_TASK = 32


def _rectangle_solid_angle(u0, u1, v0, v1):
    """Exact solid angle of the rectangle [u0, u1] x [v0, v1] on the plane at distance 1."""

    def f(u, v):
        return np.arctan2(u * v, np.sqrt(u * u + v * v + 1.0))

    return f(u1, v1) - f(u0, v1) - f(u1, v0) + f(u0, v0)


def _polygon_vector(corners: FloatArray) -> FloatArray:
    """Exact int w dw over spherical polygons with great-circle edges (Arvo 1995):
    1/2 sum_k theta_k unit(c_k x c_k+1), for corners (..., k, 3) in counter-clockwise
    order seen from outside the sphere (the result points into the polygon)."""
    c = corners / np.linalg.norm(corners, axis=-1, keepdims=True)
    out = np.zeros(c.shape[:-2] + (3,))
    k = c.shape[-2]
    for i in range(k):
        a, b = c[..., i, :], c[..., (i + 1) % k, :]
        cross = np.cross(a, b)
        length = np.linalg.norm(cross, axis=-1, keepdims=True)
        angle = np.arctan2(length, np.sum(a * b, axis=-1, keepdims=True))
        out += 0.5 * angle * cross / length
    return out


@functools.lru_cache(maxsize=8)
def cube_texels(size: int) -> tuple[FloatArray, FloatArray]:
    """Exact solid angles (6, S, S) and vector integrals (6, S, S, 3) of cube-map texels.

    Texel (f, i, j) spans u in [-1 + 2i/S, -1 + 2(i+1)/S] (and likewise v) on face f.
    The solid angles sum to 4 pi and the vectors to 0 (up to rounding).
    """
    edges = np.linspace(-1.0, 1.0, size + 1)
    u0, v0 = np.meshgrid(edges[:-1], edges[:-1], indexing="ij")
    u1, v1 = np.meshgrid(edges[1:], edges[1:], indexing="ij")
    weights = np.zeros((6, size, size))
    vectors = np.zeros((6, size, size, 3))
    for f in range(6):
        weights[f] = _rectangle_solid_angle(u0, u1, v0, v1)
        corners = np.stack(
            [face_directions(f, u, v) for u, v in ((u0, v0), (u1, v0), (u1, v1), (u0, v1))], axis=-2
        )
        vec = _polygon_vector(corners)
        centre = face_directions(f, 0.5 * (u0 + u1), 0.5 * (v0 + v1))
        # the corner order is clockwise on faces whose (u, v, axis) frame is left-handed
        flip = np.sign(np.sum(vec * centre, axis=-1, keepdims=True))
        vectors[f] = vec * flip
    weights.setflags(write=False)
    vectors.setflags(write=False)
    return weights, vectors


def raster_occlusion(
    positions,
    faces,
    points,
    *,
    size: int = FieldOptions.raster_size,
    threads: int | None = None,
    progress: Progress | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Solid angle and occluded vector integral of a triangle mesh seen from points.

    Parameters
    ----------
    positions : (nv, 3) float
        Occluder vertices.
    faces : (m, 3) int
        Occluder triangles (either side occludes).
    points : (n, 3) float
        Where to measure, in the frame of ``positions``.
    size : int
        Cube-map edge in texels (6 size^2 directions per point).
    threads : int, optional
        numba threads (default: all); the result does not depend on it.
    progress : Progress, optional

    Returns
    -------
    omega : (n,) float64 in [0, 4 pi]
        Omega(x) = int V dw, V = 1 where the occluder is seen.
    vectors : (n, 3) float64
        int V w dw; Y(x) is its direction, |vectors| <= omega.

    Notes
    -----
    Coordinates are recentred on the occluder's bounding-box centre in float64. A
    triangle through the point itself covers nothing (it projects to a line).
    """
    size = int(size)
    if size < 1:
        raise ValueError(f"size must be >= 1, got {size}")
    positions = np.asarray(positions, dtype=np.float64)
    centre = 0.5 * (positions.min(axis=0) + positions.max(axis=0))
    vertices = np.ascontiguousarray(positions - centre)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    points = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3) - centre)
    weights, vectors = cube_texels(size)
    out = np.zeros((points.shape[0], 4))
    progress = progress or NullProgress()
    progress.start(points.shape[0], "raster")

    def render(index: np.ndarray) -> int:
        s, e = int(index[0]), int(index[-1]) + 1
        _k.render_points(vertices, faces, points[s:e], weights, vectors, out[s:e])
        return e - s

    with numba_threads(threads):
        workers = numba.get_num_threads()
    # each point is drawn on its own: the result does not depend on the threads
    trace_chunks(split(np.arange(points.shape[0]), _TASK), render, threads=workers, progress=progress)
    progress.finish()
    if not np.isfinite(out).all() or out[:, 0].min(initial=0.0) < 0 or out[:, 0].max(initial=0.0) > 4 * math.pi + 1e-9:
        raise NumericalError("raster: solid angle not finite or outside [0, 4 pi]")
    return out[:, 0].copy(), out[:, 1:].copy()
