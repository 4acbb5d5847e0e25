"""Ambient occlusion fields (Kontkanen & Laine 2005): fit around a rigid occluder, evaluate.

An :class:`AOField` stores, per direction of a cube map around the occluder's centre,
seven scalars: a, b, c of the solid-angle model Omega(r) = 1/(a r^2 + b r + c), the
hull distance r0 and the characteristic point C_o of the mean occluded direction
Y(r) = normalize(C_o - x). :func:`fit_field` samples Omega and Y around the occluder
(cube-map rasterizer or Embree rays) and fits them; :func:`field_ao` / :func:`fields_ao`
evaluate one or several (rigidly moved) fields at receiver vertices; :func:`save_field`
and :func:`load_field` own the ``.npz`` format. Numpy-facing wrappers of
``aobake.kernels.field`` (no @njit code here); never prints.

References
----------
J. Kontkanen and S. Laine, "Ambient Occlusion Fields", Proc. I3D 2005, 41-48.
J. Snyder, "Area Light Sources for Real-Time Graphics", Microsoft Research TR-96-11 (1996).
J. Arvo, "Applications of Irradiance Tensors to the Simulation of Non-Lambertian
Phenomena", SIGGRAPH 1995 (exact vector integral of a spherical polygon).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import time
import zipfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._types import AOArray, FloatArray
from .constants import CHUNK_RAYS
from .errors import InputError, NumericalError
from .kernels import field as _k
from .kernels import rays as _rays
from .mesh import Surface, face_normals_and_areas
from .progress import NullProgress, Progress
from .raster import DEFAULT_RASTER_SIZE, face_directions, raster_occlusion

SAMPLERS = ("raster", "embree")
#: Radial models (see :func:`fit_field`).
MODELS = {"paper": _k.MODEL_PAPER, "cap": _k.MODEL_CAP, "table": _k.MODEL_TABLE}

#: ``field.npz`` layout version; :func:`load_field` refuses any other.
FORMAT_VERSION = 1

# Cube-map texels per face edge: the bench's bunny RMSE flattens out beyond 16 because
# the radial model, not the angular resolution, limits accuracy (bench/bench_field.py).
DEFAULT_RESOLUTION = 16
# Radial samples per texel, log-spaced from the hull to r_far (15 beat 8 clearly in the
# issue's prototype; more cost linearly).
DEFAULT_RADIAL_SAMPLES = 15
# Rays per sample point for the Embree sampler (uniform over the sphere, Owen-scrambled
# Sobol): Omega's standard error is below 4 pi sqrt(p (1 - p) / N), ~0.2 sr at N = 1024
# in the worst case and much less with stratification; the fit averages 15 of them.
DEFAULT_FIELD_RAYS = 1024
# r_far = R_FAR_FACTOR * bounding radius: a sphere of that radius seen from 8 radii
# subtends 0.05 sr (A <= 1/64 for any normal), so cutting the field there changes AO by
# at most ~0.016, and the fade from r_near hides the cut.
R_FAR_FACTOR = 8.0
# The fade to zero starts at R_NEAR_FRACTION * r_far (smoothstep to r_far).
R_NEAR_FRACTION = 0.5
# First radial sample at r0 + HULL_MARGIN * bounding radius: just outside the hull, so
# a sample never sits on a surface where a triangle through it would project to a line.
HULL_MARGIN = 1e-3
# Inside the hull A is blended towards A0 with t = (r / r0)^HULL_POWER: the centre of a
# solid occluder is fully occluded (A0 = 1); the power keeps the model's value near the
# hull, where receivers touch the occluder.
DEFAULT_A0 = 1.0
DEFAULT_HULL_POWER = 2.0
# Box prefilter: the raster sampler averages PREFILTER^2 sub-directions per texel; the
# Embree sampler spreads each sample's rays over the texel's footprint (free). Off by
# default: on the bench's bunny it raised the RMSE from 0.012 to 0.015-0.018, because
# the bilinear lookup already blurs over a texel and the contact ring is sharp.
DEFAULT_PREFILTER = 1
# "cap" keeps the paper's 7 scalars but models the cap's half-angle instead of Omega,
# 1/sin^2(sigma) = a r^2 + b r + c (exact for a sphere and a disk on its axis): RMSE
# 0.0117 vs 0.0120 for the paper's 1/Omega on the bench; "table" stores the samples.
DEFAULT_MODEL = "cap"
# Support-plane normals for the hull distance: the centres of a 6 x 32^2 cube map.
SUPPORT_GRID = 32
# Levenberg-Marquardt iterations: Omega in its own space after the linear fit, C_o.
OMEGA_ITERS = 8
CENTRE_ITERS = 20
# Y weights q_i (Omega_i / max)^Y_POWER: the AO error of a direction error scales with
# Omega; the quadrature weights q_i = (share of r) * r^Q_POWER make far samples count
# for the many receivers there (Q_POWER = 1: receivers on a plane). Measured on the
# bench's ground grid: RMSE 0.0162 without q, 0.0120 with Q_POWER = 1, 0.0127 with 2.
Y_POWER = 2.0
Q_POWER = 1.0
# Cap integral table for evaluation: measured 9-10x faster than the closed form
# (250 vs 28 M lookups/s on one core) with a largest deviation of 3.3e-4 (RMS 7e-6),
# 30x below the field's own RMSE; the closed form builds it and stays public.
CAP_LUT = 256
# Sample points per raster call / rays per Embree call: progress and memory only.
_RASTER_CHUNK = 2048


# --------------------------------------------------------------------------------------
# the field


@dataclass(frozen=True)
class AOField:
    """A fitted ambient occlusion field (see the module docstring).

    Attributes
    ----------
    texels : (6, R + 2, R + 2, 7) float32
        Per cube-map texel: a, b, c, r0, C_o (x, y, z), in the occluder's units and
        relative to ``centre``. Face f has major axis ``kernels.raster.FACE_AXIS[f]``;
        index 0 and R + 1 along each face edge are a one-texel border fitted at the
        directions just past the edge, so bilinear lookup never crosses faces.
    residuals : (6, R + 2, R + 2, 2) float32
        RMS fit error per texel: Omega (steradians) and Y (degrees).
    centre : (3,) float64
        Area-weighted centroid of the occluder's surface (inside its convex hull).
    radius : float
        Largest distance from ``centre`` to a vertex.
    r_far, r_near : float
        No influence at or beyond r_far; a smoothstep fade from r_near.
    a0, power : float
        Inside the hull A blends towards ``a0`` with t = (r / r0)^power.
    resolution : int
        R, texels per face edge (without the border).
    model : {"paper", "cap", "table"}
        How Omega depends on r (see :func:`fit_field`).
    table : (6, R + 2, R + 2, M, 4) float32 or None
        The table model's knots: Omega and int V w dw at r0 + d_i.
    d_min, d_max : float
        The radial layout: d_i log-spaced from d_min to d_max (see :func:`radial_layout`).
    params : dict
        Fit options (sampler, radial_samples, raster_size or rays, prefilter, seed).
    occluder_name, occluder_hash : str
        Source name and SHA-256 of the occluder's float64 positions and int64 faces.
    """

    texels: np.ndarray
    residuals: np.ndarray
    centre: FloatArray
    radius: float
    r_far: float
    r_near: float
    a0: float
    power: float
    resolution: int
    model: str = DEFAULT_MODEL
    table: np.ndarray | None = None
    d_min: float = 0.0
    d_max: float = 0.0
    params: dict = field(default_factory=dict)
    occluder_name: str = ""
    occluder_hash: str = ""
    #: Wall time of :func:`fit_field` (0 for a loaded field; not saved).
    seconds: float = field(default=0.0, compare=False)

    @property
    def omega_rms(self) -> float:
        """RMS of the per-texel Omega residuals (steradians)."""
        return float(np.sqrt(np.mean(self.residuals[..., 0].astype(np.float64) ** 2)))

    @property
    def y_rms_degrees(self) -> float:
        """RMS of the per-texel Y residuals (degrees)."""
        return float(np.sqrt(np.mean(self.residuals[..., 1].astype(np.float64) ** 2)))

    @property
    def nbytes(self) -> int:
        """Bytes of the per-texel arrays (what a renderer would upload)."""
        return int(self.texels.nbytes + (0 if self.table is None else self.table.nbytes))

    def kernel_config(self) -> FloatArray:
        """(7,) float64: what ``kernels.field.evaluate`` reads (see its docstring)."""
        knots = 0 if self.table is None else self.table.shape[3]
        per_log = (knots - 1) / math.log(self.d_max / self.d_min) if knots > 1 else 0.0
        return np.array([self.r_far, self.r_near, self.a0, self.power, MODELS[self.model], self.d_min, per_log])


@dataclass(frozen=True)
class FieldAO:
    """Result of :func:`fields_ao`.

    Attributes
    ----------
    ao : (n,) float64 in [0, 1]
        prod_k (1 - A_k) over the fields.
    skipped : tuple of int
        Receivers at or beyond each field's r_far (not evaluated, factor 1).
    seconds : float
        Evaluation wall time.
    """

    ao: AOArray
    skipped: tuple[int, ...]
    seconds: float


# --------------------------------------------------------------------------------------
# geometry helpers


def surface_centre(positions: FloatArray, faces) -> FloatArray:
    """Area-weighted centroid of the triangles (a convex combination of vertices, so it
    lies inside the convex hull); the vertex mean when every face has zero area."""
    positions = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    _, areas = face_normals_and_areas(positions, faces)
    total = areas.sum()
    if not total > 0.0:
        return positions[np.unique(faces)].mean(axis=0)
    centroids = positions[faces].mean(axis=1)
    return (areas[:, None] * centroids).sum(axis=0) / total


def _unit(v: FloatArray) -> FloatArray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _support_points(local: FloatArray) -> np.ndarray:
    """Indices of the vertices extreme along 6 K^2 cube-map directions (hull vertices)."""
    grid = (np.arange(SUPPORT_GRID) + 0.5) * (2.0 / SUPPORT_GRID) - 1.0
    u, v = np.meshgrid(grid, grid, indexing="ij")
    planes = np.ascontiguousarray(_unit(np.concatenate([face_directions(f, u, v).reshape(-1, 3) for f in range(6)])))
    h = np.zeros(planes.shape[0])
    arg = np.zeros(planes.shape[0], dtype=np.int64)
    _k.support_values(local, planes, h, arg)
    return np.unique(arg).astype(np.int64)


def hull_distance(positions, directions, centre) -> FloatArray:
    """Distance from ``centre`` along unit ``directions`` to the boundary of the convex
    hull of ``positions`` (no hull is built, and scipy is not needed).

    Parameters
    ----------
    positions : (n, 3) float
    directions : (k, 3) float
        Normalised here.
    centre : (3,) float
        Must lie inside the hull (:func:`surface_centre` does).

    Returns
    -------
    r0 : (k,) float64, >= 0

    Notes
    -----
    c + t w lies in the hull iff t w = sum lam_v (v - c) for barycentric weights lam:
    r0 is the largest such t, a linear program with three equality rows (weights sum
    to one, no component across w). It is solved exactly by the simplex method, whose
    basis is a triangle of vertices whose projection along w contains the axis; the
    vertices extreme along 6 x 32^2 directions go first, then all vertices verify the
    optimum. This is the dual of the support-function form r0 = min over m of
    (h(m) - m.c)/(m.w), which a dense set of m only bounds from above (tests compare
    with the exact face-by-face distance of convex polyhedra: equal to ~1e-13).
    """
    local = np.ascontiguousarray(np.asarray(positions, dtype=np.float64) - np.asarray(centre, dtype=np.float64))
    dirs = np.ascontiguousarray(_unit(np.asarray(directions, dtype=np.float64).reshape(-1, 3)))
    out = np.zeros(dirs.shape[0])
    _k.hull_distances(dirs, _support_points(local), local, out)
    return out


def texel_anchors(resolution: int) -> FloatArray:
    """Unnormalised directions (6, R + 2, R + 2, 3) of the padded texel centres.

    Texel i (0 .. R + 1) of a face has face coordinate u = (2 i - 1) / R - 1: 0 and
    R + 1 are the border texels just past the face's edges.
    """
    u = (2.0 * np.arange(resolution + 2) - 1.0) / resolution - 1.0
    uu, vv = np.meshgrid(u, u, indexing="ij")
    return np.stack([face_directions(f, uu, vv) for f in range(6)])


def radial_layout(r0: FloatArray, r_far: float, radius: float, m: int) -> tuple[FloatArray, float, float]:
    """Sample distances per texel: r0 + d_i, the same d_i for every texel, log-spaced
    from d_min = HULL_MARGIN * radius to d_max = r_far - min(r0).

    Half the samples lie within ~0.1 radius of the hull, where Omega and Y change
    fastest (contacts); log-spacing r itself from r0 would leave nothing between 1e-3
    and ~0.2 radius from the hull. Knots beyond r_far (texels with a large r0) are
    sampled but not fitted.

    Returns
    -------
    radii : (T, M) float64
    d_min, d_max : float
    """
    r0 = np.asarray(r0, dtype=np.float64)
    d_min = HULL_MARGIN * radius
    d_max = max(r_far - float(r0.min(initial=0.0)), 2.0 * d_min)
    d = d_min * (d_max / d_min) ** np.linspace(0.0, 1.0, m)
    return r0[:, None] + d[None, :], d_min, d_max


def quadrature_weights(radii: FloatArray, r_far: float) -> FloatArray:
    """(T, M) share of space each radial sample stands for, normalised per texel: the
    sample's interval in r (half the gaps to its neighbours) times r^Q_POWER; 0 beyond
    r_far."""
    edges = np.concatenate([radii[:, :1], 0.5 * (radii[:, 1:] + radii[:, :-1]), radii[:, -1:]], axis=1)
    q = np.diff(edges, axis=1) * radii**Q_POWER
    q[radii > r_far * (1.0 + 1e-12)] = 0.0
    return q / np.maximum(q.max(axis=1, keepdims=True), 1e-300)


def _face_tangents(resolution: int) -> FloatArray:
    """(6, R + 2, R + 2, 6): the texel's edge vectors t_u, t_v in anchor space (2/R long)."""
    out = np.zeros((6, resolution + 2, resolution + 2, 6))
    for f in range(6):
        out[f, :, :, 0:3] = face_directions(f, 1.0, 0.0) - face_directions(f, 0.0, 0.0)
        out[f, :, :, 3:6] = face_directions(f, 0.0, 1.0) - face_directions(f, 0.0, 0.0)
    return out * (2.0 / resolution)


# --------------------------------------------------------------------------------------
# samplers


def _embree_samples(positions, faces, geometry, *, n_rays, seed, threads, progress) -> FloatArray:
    """(n, 4) Omega and int V w dw from ``n_rays`` rays per point (see kernels.field)."""
    from .tracing import Tracer

    anchors, tangents, radii, centre = geometry
    tracer = Tracer(positions, faces)
    shift = np.asarray(centre, dtype=np.float64) - tracer.center
    geom = (
        np.ascontiguousarray(anchors, dtype=np.float64),
        np.ascontiguousarray(tangents, dtype=np.float64),
        np.ascontiguousarray(radii, dtype=np.float64),
        np.ascontiguousarray(shift),
    )
    n = geom[0].shape[0]
    keys = _rays.vertex_keys(np.uint64(seed), n)
    out = np.zeros((n, 4))
    per_chunk = max(1, CHUNK_RAYS // 4 // n_rays)
    chunks = [np.arange(s, min(n, s + per_chunk), dtype=np.int64) for s in range(0, n, per_chunk)]

    def trace(index: np.ndarray) -> int:
        k = index.size * n_rays
        org = np.zeros((k, 3), dtype=np.float32)
        dirs = np.zeros((k, 3), dtype=np.float32)
        _k.footprint_rays(geom, keys, index, n_rays, org, dirs)
        ids = tracer.occluded(org, dirs)
        _k.accumulate_hits(ids, dirs, n_rays, index, out)
        return index.size

    workers = max(1, int(threads or os.cpu_count() or 1))
    pool = ThreadPoolExecutor(max_workers=workers)
    try:
        for done in pool.map(trace, chunks):
            progress.advance(done)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    out *= 4.0 * math.pi / n_rays
    return out


def embree_occlusion(
    positions,
    faces,
    points,
    *,
    n_rays: int = DEFAULT_FIELD_RAYS,
    seed: int = 0,
    threads: int | None = None,
    progress: Progress | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Solid angle and occluded vector integral at points, by Embree rays over the sphere.

    Parameters
    ----------
    positions : (nv, 3) float
    faces : (m, 3) int
    points : (n, 3) float
    n_rays : int
        Rays per point: uniform directions on the sphere from an Owen-scrambled Sobol
        sequence keyed by (seed, point index).
    seed : int
    threads : int, optional
    progress : Progress, optional

    Returns
    -------
    omega : (n,) float64
        4 pi hits / n_rays: unbiased for Omega = int V dw.
    vectors : (n, 3) float64
        4 pi / n_rays * sum of the hit directions: unbiased for int V w dw.
    """
    n_rays = int(n_rays)
    if n_rays < 1:
        raise ValueError(f"n_rays must be >= 1, got {n_rays}")
    positions = np.asarray(positions, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    centre = 0.5 * (positions.min(axis=0) + positions.max(axis=0))
    anchors = points - centre
    geometry = (anchors, np.zeros((points.shape[0], 6)), np.linalg.norm(anchors, axis=1), centre)
    progress = progress or NullProgress()
    progress.start(points.shape[0], "embree")
    out = _embree_samples(
        positions,
        np.asarray(faces, dtype=np.int64),
        geometry,
        n_rays=n_rays,
        seed=seed,
        threads=threads,
        progress=progress,
    )
    progress.finish()
    return out[:, 0].copy(), out[:, 1:].copy()


# --------------------------------------------------------------------------------------
# fitting


def _check_int(name: str, value, low: int) -> int:
    if isinstance(value, bool) or int(value) != value or int(value) < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def occluder_hash(positions: FloatArray, faces) -> str:
    """SHA-256 (hex) of the occluder's float64 positions and int64 faces."""
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(positions, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    return digest.hexdigest()


def fit_field(
    surface: Surface,
    *,
    sampler: str = "raster",
    resolution: int = DEFAULT_RESOLUTION,
    radial_samples: int = DEFAULT_RADIAL_SAMPLES,
    raster_size: int = DEFAULT_RASTER_SIZE,
    rays: int = DEFAULT_FIELD_RAYS,
    r_far: float | None = None,
    prefilter: int = DEFAULT_PREFILTER,
    model: str = DEFAULT_MODEL,
    seed: int = 0,
    threads: int | None = None,
    progress: Progress | None = None,
) -> AOField:
    """Fit an ambient occlusion field around a rigid occluder.

    Parameters
    ----------
    surface : Surface
        The occluder (its triangles; either side occludes).
    sampler : {"raster", "embree"}
        How Omega and Y are measured at the sample points: cube maps rasterized on the
        CPU (``raster_size`` texels per edge), or ``rays`` Embree rays over the sphere.
    resolution : int
        R, cube-map texels per face edge of the field (6 R^2 directions, plus a border).
    radial_samples : int
        M >= 3 sample distances per texel, log-spaced from just outside the convex hull
        (r0) to r_far.
    raster_size, rays : int
        Sampler quality (the other sampler ignores it).
    r_far : float, optional
        Outer radius of the field, from the centre; default ``R_FAR_FACTOR`` (8) times
        the bounding radius. Must exceed the bounding radius.
    prefilter : int
        Box prefilter over each texel's footprint: the raster sampler averages
        ``prefilter^2`` sub-directions; the Embree sampler spreads each sample's rays
        over the footprint when ``prefilter > 1`` (at no cost). 1 = point samples
        (the default: prefiltering measured worse on the bench, 0.015 vs 0.011).
    model : {"cap", "paper", "table"}
        The radial model (see Notes): 7 scalars per texel, or the sample table.
    seed : int
        Key of the Embree sampler's ray sets (the raster sampler is deterministic).
    threads : int, optional
        Worker threads (default: all cores); the result does not depend on it.
    progress : Progress, optional

    Returns
    -------
    AOField

    Raises
    ------
    ValueError
        An unknown sampler or model, or a count out of range.
    InputError
        ``r_far`` does not exceed the occluder's bounding radius, or the occluder has no
        extent.

    Notes
    -----
    Layout: the centre is the surface's area-weighted centroid; per texel direction w,
    r0 is the exact distance to the convex hull (:func:`hull_distance`; the largest over
    the footprint when prefiltered) and the M samples sit at r0 + d_i with d_i
    log-spaced from 1e-3 bounding radii to r_far (:func:`radial_layout`), so the
    contact region gets half of them.

    Fits per texel (DESIGN.md section 4), with quadrature weights q_i = (the sample's
    share of r) x r_i, the room each sample stands for on a receiving plane
    (:func:`quadrature_weights`):

    - Omega: den(r) = a r^2 + b r + c is 1/Omega (``model="paper"``) or 1/sin^2(sigma)
      of the cap with the same solid angle (``"cap"``, the default: exact for a sphere
      and for a disk seen on its axis, and Omega <= 2 pi by construction). Weighted
      linear least squares on den with weights (dOmega/dden)^2 (Omega^4 for the paper's
      model: the error in Omega), with den kept >= 1/(4 pi) (paper) or 1/2 (cap) on
      [r0, r_far] by equality constraints at the worst points (else a constant), then
      Levenberg-Marquardt on sum q_i (Omega_i - Omega~_i)^2, the paper's error sum.
    - Y: C_o starts at the point closest to the lines x_i + t Y_i (weights w_i = q_i
      (Omega_i / max)^2, a small ridge towards the centre: parallel Y_i stay solvable)
      and at the centre; Levenberg-Marquardt on sum w_i |Y~_i - Y_i|^2 = 2 sum w_i (1 -
      Y~_i.Y_i), whose residual is linear in the angle (the paper's squared form is flat
      at its optimum), keeps C_o.w <= r0 so Y~ seen from outside the hull points into
      it; the better start wins.
    - ``model="table"`` stores the samples themselves as well (M knots of Omega and
      int V w dw per texel) and evaluates them, the 7 scalars holding the cap fit.

    Samples with Omega = 0 are dropped; a texel with no sample at all gets a = b = c = 0
    (Omega = 0). Residuals use the same weights. Measured on the bench (bunny on a
    ground grid, N = 16): RMSE 0.011 (cap), 0.012 (paper), 0.0074 (table), against
    0.0045 for the spherical-cap approximation with exact Omega and Y.
    """
    t0 = time.perf_counter()
    if sampler not in SAMPLERS:
        raise ValueError(f"sampler must be one of {', '.join(SAMPLERS)}, got {sampler!r}")
    if model not in MODELS:
        raise ValueError(f"model must be one of {', '.join(MODELS)}, got {model!r}")
    resolution = _check_int("resolution", resolution, 1)
    radial_samples = _check_int("radial_samples", radial_samples, 3)
    raster_size = _check_int("raster_size", raster_size, 1)
    rays = _check_int("rays", rays, 1)
    prefilter = _check_int("prefilter", prefilter, 1)
    progress = progress or NullProgress()

    positions = np.ascontiguousarray(surface.positions, dtype=np.float64)
    faces = np.ascontiguousarray(surface.faces, dtype=np.int64)
    centre = surface_centre(positions, faces)
    local = np.ascontiguousarray(positions - centre)
    radius = float(np.linalg.norm(local, axis=1).max())
    if not radius > 0.0:
        raise InputError(surface.source, "occluder has no extent (all vertices coincide)")
    if r_far is None:
        r_far = R_FAR_FACTOR * radius
    r_far = float(r_far)
    if not (math.isfinite(r_far) and r_far > radius):
        raise InputError(surface.source, f"r_far {r_far:.6g} must exceed the occluder's bounding radius {radius:.6g}")

    from .checks import numba_threads

    res = resolution
    n_side = res + 2
    anchors = texel_anchors(res)  # (6, P, P, 3)
    tangents = _face_tangents(res)  # (6, P, P, 6)
    dirs = _unit(anchors).reshape(-1, 3)
    n_tex = dirs.shape[0]

    with numba_threads(threads):
        # r0: hull distance, the largest over the footprint when it is prefiltered, so
        # no sample of a texel falls inside the hull
        candidates = _support_points(local)
        offsets = [(0.0, 0.0)] if prefilter == 1 else [(a, b) for a in (-0.5, 0.0, 0.5) for b in (-0.5, 0.0, 0.5)]
        flat_anchor = anchors.reshape(-1, 3)
        flat_tan = tangents.reshape(-1, 6)
        r0 = np.zeros(n_tex)
        for a, b in offsets:
            q = np.ascontiguousarray(_unit(flat_anchor + a * flat_tan[:, :3] + b * flat_tan[:, 3:]))
            d = np.zeros(n_tex)
            _k.hull_distances(q, candidates, local, d)
            r0 = np.maximum(r0, d)
        radii, d_min, d_max = radial_layout(r0, r_far, radius, radial_samples)  # (T, M)

        n_pts = n_tex * radial_samples
        if sampler == "raster":
            sub = (np.arange(prefilter) + 0.5) / prefilter - 0.5
            subs = [(a, b) for a in sub for b in sub]
            progress.start(n_pts * len(subs), f"field (raster {raster_size})")
            samples = np.zeros((n_tex, radial_samples, 4))
            for a, b in subs:
                q = _unit(flat_anchor + a * flat_tan[:, :3] + b * flat_tan[:, 3:])
                pts = (centre + radii[:, :, None] * q[:, None, :]).reshape(-1, 3)
                for s in range(0, n_pts, _RASTER_CHUNK):
                    om, vec = raster_occlusion(positions, faces, pts[s : s + _RASTER_CHUNK], size=raster_size)
                    block = samples.reshape(-1, 4)[s : s + _RASTER_CHUNK]
                    block[:, 0] += om
                    block[:, 1:] += vec
                    progress.advance(om.shape[0])
            samples /= len(subs)
        else:
            progress.start(n_pts, f"field (embree {rays} rays)")
            tan = flat_tan if prefilter > 1 else np.zeros_like(flat_tan)
            geometry = (
                np.repeat(flat_anchor, radial_samples, axis=0),
                np.repeat(tan, radial_samples, axis=0),
                radii.reshape(-1),
                centre,
            )
            samples = _embree_samples(
                positions, faces, geometry, n_rays=rays, seed=seed, threads=threads, progress=progress
            ).reshape(n_tex, radial_samples, 4)
        progress.finish()

        params = np.zeros((n_tex, _k.N_PARAMS))
        resid = np.zeros((n_tex, 2))
        fit_model = _k.MODEL_CAP if model == "table" else MODELS[model]
        settings = np.array([OMEGA_ITERS, CENTRE_ITERS, Y_POWER, fit_model], dtype=np.float64)
        radial = np.ascontiguousarray(np.stack([radii, quadrature_weights(radii, r_far)], axis=-1))
        samples = np.ascontiguousarray(samples)
        _k.fit_texels(radial, samples, np.ascontiguousarray(dirs), r0, r_far, settings, params, resid)
    if not (np.isfinite(params).all() and np.isfinite(resid).all()):
        raise NumericalError(f"{surface.source}: field fit produced non-finite parameters")
    options = {"sampler": sampler, "radial_samples": radial_samples, "prefilter": prefilter}
    if sampler == "raster":
        options["raster_size"] = raster_size
    else:
        options.update(rays=rays, seed=int(seed))
    out = AOField(
        texels=params.astype(np.float32).reshape(6, n_side, n_side, _k.N_PARAMS),
        residuals=resid.astype(np.float32).reshape(6, n_side, n_side, 2),
        centre=centre,
        radius=radius,
        r_far=r_far,
        r_near=R_NEAR_FRACTION * r_far,
        a0=DEFAULT_A0,
        power=DEFAULT_HULL_POWER,
        resolution=res,
        model=model,
        table=samples.astype(np.float32).reshape(6, n_side, n_side, radial_samples, 4) if model == "table" else None,
        d_min=d_min,
        d_max=d_max,
        params=options,
        occluder_name=surface.source,
        occluder_hash=occluder_hash(positions, faces),
        seconds=time.perf_counter() - t0,
    )
    _validate(out, surface.source)
    return out


# --------------------------------------------------------------------------------------
# evaluation


def cap_integral(omega, cos_theta) -> FloatArray:
    """Cosine-weighted occlusion of a spherical cap, C(Omega, cos theta) in [0, 1].

    C = 1/pi int_cap max(0, n.w) dw for a cap of solid angle ``omega`` (half-angle
    sigma, cos sigma = 1 - Omega/2pi) whose axis makes angle theta with n: Snyder's
    closed form, with the complement for sigma > pi/2 and the sigma = pi/2 limit.
    C(pi, 1) = 0.75, C(pi, 0) = 0.1955, C(2 pi, 0) = 0.5.

    Parameters
    ----------
    omega, cos_theta : array_like, broadcast together
        Omega is clamped to [0, 4 pi], cos theta to [-1, 1].

    Returns
    -------
    (broadcast shape) float64
    """
    om, ct = np.broadcast_arrays(np.asarray(omega, dtype=np.float64), np.asarray(cos_theta, dtype=np.float64))
    shape = om.shape
    om = np.ascontiguousarray(om.reshape(-1))
    ct = np.ascontiguousarray(ct.reshape(-1))
    out = np.zeros(om.shape[0])
    _k.cap_occlusion_array(om, ct, out)
    return out.reshape(shape)


@functools.lru_cache(maxsize=1)
def cap_table() -> np.ndarray:
    """(CAP_LUT + 1, CAP_LUT + 1) float32 table of :func:`cap_integral` over Omega in
    [0, 4 pi] and cos theta in [-1, 1], read bilinearly by the evaluation kernel."""
    om = np.linspace(0.0, 4.0 * math.pi, CAP_LUT + 1)
    ct = np.linspace(-1.0, 1.0, CAP_LUT + 1)
    table = cap_integral(om[:, None], ct[None, :]).astype(np.float32)
    table.setflags(write=False)
    return table


def rigid_transform(translation=(0.0, 0.0, 0.0), rotation_degrees=(0.0, 0.0, 0.0)) -> FloatArray:
    """4 x 4 matrix placing an occluder: rotate about the fixed x, then y, then z axes
    (degrees, right-handed), then translate. The CLI's ``FIELD@tx,ty,tz,rx,ry,rz``.

    Returns
    -------
    (4, 4) float64
        ``M @ [x, 1]`` maps occluder coordinates to world coordinates.
    """
    rx, ry, rz = np.radians(np.asarray(rotation_degrees, dtype=np.float64))
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    rot_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    rot_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rot_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    out = np.eye(4)
    out[:3, :3] = rot_z @ rot_y @ rot_x
    out[:3, 3] = np.asarray(translation, dtype=np.float64)
    return out


def _field_frame(f: AOField, transform) -> FloatArray:
    """(4, 3) world-to-field frame for the kernel; checks the transform is rigid."""
    if transform is None:
        rot, trans = np.eye(3), np.zeros(3)
    else:
        m = np.asarray(transform, dtype=np.float64)
        if m.shape == (4, 4):
            if not np.allclose(m[3], [0, 0, 0, 1]):
                raise ValueError("transform: the last row of a 4 x 4 rigid transform must be 0, 0, 0, 1")
            rot, trans = m[:3, :3], m[:3, 3]
        elif m.shape == (3, 4):
            rot, trans = m[:, :3], m[:, 3]
        else:
            raise ValueError(f"transform must be a (4, 4) or (3, 4) matrix, got shape {m.shape}")
        if not np.isfinite(m).all():
            raise ValueError("transform has NaN or inf entries")
        if not (np.allclose(rot.T @ rot, np.eye(3), atol=1e-9) and np.linalg.det(rot) > 0):
            raise ValueError("transform must be rigid: a rotation (orthonormal, det +1) and a translation")
    frame = np.zeros((4, 3))
    frame[:3] = rot.T  # world -> occluder: R^T (x - t) - centre
    frame[3] = -rot.T @ trans - f.centre
    return frame


_NO_TABLE = np.zeros((1, 1, 1, 2, 4), dtype=np.float32)


def _eval_texels(f: AOField) -> np.ndarray:
    """(6, R + 2, R + 2, 10) float32: the 7 scalars and the texel's unit direction."""
    out = np.zeros(f.texels.shape[:3] + (_k.N_EVAL,), dtype=np.float32)
    out[..., : _k.N_PARAMS] = f.texels
    out[..., _k.P_WX :] = _unit(texel_anchors(f.resolution))
    return out


def fields_ao(
    fields,
    positions,
    normals,
    *,
    transforms=None,
    threads: int | None = None,
) -> FieldAO:
    """Accessibility 1 - A at receivers from several rigid occluders' fields.

    Parameters
    ----------
    fields : sequence of AOField
    positions : (n, 3) float
        Receiver points (world space).
    normals : (n, 3) float
        Receiver normals; zero rows read as "no normal" (cos theta = 0).
    transforms : sequence of (4, 4) float or None, optional
        Per field, the rigid occluder-to-world transform (rotation + translation, see
        :func:`rigid_transform`); None = identity.
    threads : int, optional

    Returns
    -------
    FieldAO
        ``ao`` = prod_k (1 - A_k), and per field the receivers skipped beyond r_far.

    Notes
    -----
    The product is exact only when the occluders block uncorrelated sets of directions
    (Kontkanen & Laine, section 5): overlapping occluders come out too dark.
    """
    from .checks import numba_threads

    t0 = time.perf_counter()
    fields = list(fields)
    transforms = [None] * len(fields) if transforms is None else list(transforms)
    if len(transforms) != len(fields):
        raise ValueError(f"{len(fields)} fields but {len(transforms)} transforms")
    positions = np.ascontiguousarray(np.asarray(positions, dtype=np.float64).reshape(-1, 3))
    normals = np.ascontiguousarray(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
    if normals.shape != positions.shape:
        raise ValueError(f"normals have shape {normals.shape}, positions {positions.shape}")
    if not np.isfinite(positions).all():
        raise ValueError("receiver positions have NaN or inf entries")
    if not np.isfinite(normals).all():
        normals = np.where(np.isfinite(normals), normals, 0.0)  # "no normal"
    ao = np.ones(positions.shape[0])
    skipped = []
    with numba_threads(threads):
        for f, transform in zip(fields, transforms, strict=True):
            frame = _field_frame(f, transform)
            flags = np.zeros(positions.shape[0], dtype=np.uint8)
            table = _NO_TABLE if f.table is None else np.ascontiguousarray(f.table, dtype=np.float32)
            arrays = (_eval_texels(f), table, cap_table())
            _k.evaluate(arrays, f.kernel_config(), frame, positions, normals, ao, flags)
            skipped.append(int(flags.sum()))
    # min/max propagate NaN, and NaN fails both comparisons
    if not (ao.min(initial=1.0) >= 0.0 and ao.max(initial=0.0) <= 1.0):
        raise NumericalError("field: AO not finite or outside [0, 1]")
    return FieldAO(ao=ao, skipped=tuple(skipped), seconds=time.perf_counter() - t0)


def field_ao(f: AOField, positions, normals, *, transform=None, threads: int | None = None) -> AOArray:
    """Accessibility 1 - A at receivers from one field (see :func:`fields_ao`).

    Returns
    -------
    ao : (n,) float64 in [0, 1]
        1 where the receiver is beyond r_far.
    """
    return fields_ao([f], positions, normals, transforms=[transform], threads=threads).ao


# --------------------------------------------------------------------------------------
# file format

_SCALARS = ("radius", "r_far", "r_near", "a0", "power", "d_min", "d_max")
_STRINGS = ("model", "params", "occluder_name", "occluder_hash", "aobake_version")
_KEYS = ("format_version", "resolution", "texels", "residuals", "centre", *_SCALARS, *_STRINGS)


def save_field(f: AOField, path: str | Path) -> None:
    """Write ``f`` to ``path`` (.npz), atomically and byte-for-byte reproducibly.

    Layout (``FORMAT_VERSION`` 1): ``format_version`` and ``resolution`` (int64),
    ``texels`` (6, R+2, R+2, 7: a, b, c, r0, C_o) and ``residuals`` (6, R+2, R+2, 2)
    float32, ``centre`` (3,) and the float64 scalars ``radius``, ``r_far``,
    ``r_near``, ``a0``, ``power``, ``d_min``, ``d_max``, the strings ``model``,
    ``params`` (JSON of the fit options), ``occluder_name``, ``occluder_hash`` and
    ``aobake_version``, and for the table model ``table`` (6, R+2, R+2, M, 4) float32.
    Zip entries carry a fixed date, so the same field gives the same bytes.
    """
    from . import __version__
    from .io import atomic_write

    arrays = {
        "format_version": np.array(FORMAT_VERSION, dtype=np.int64),
        "resolution": np.array(f.resolution, dtype=np.int64),
        "texels": np.ascontiguousarray(f.texels, dtype=np.float32),
        "residuals": np.ascontiguousarray(f.residuals, dtype=np.float32),
        "centre": np.asarray(f.centre, dtype=np.float64),
        **{k: np.array(getattr(f, k), dtype=np.float64) for k in _SCALARS},
        "model": np.array(f.model),
        "params": np.array(json.dumps(f.params, sort_keys=True)),
        "occluder_name": np.array(f.occluder_name),
        "occluder_hash": np.array(f.occluder_hash),
        "aobake_version": np.array(__version__),
    }
    if f.table is not None:
        arrays["table"] = np.ascontiguousarray(f.table, dtype=np.float32)
    with atomic_write(path) as tmp, zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as zf:
        for name, arr in arrays.items():
            info = zipfile.ZipInfo(name + ".npy", date_time=(1980, 1, 1, 0, 0, 0))
            with zf.open(info, "w") as fh:
                np.lib.format.write_array(fh, arr, allow_pickle=False)


def _validate(f: AOField, where) -> None:
    """Raise InputError unless ``f`` is internally consistent."""
    res = f.resolution
    n = res + 2
    if f.texels.shape != (6, n, n, _k.N_PARAMS):
        raise InputError(where, f"texels have shape {f.texels.shape}, expected (6, {n}, {n}, 7) for resolution {res}")
    if f.residuals.shape != (6, n, n, 2):
        raise InputError(where, f"residuals have shape {f.residuals.shape}, expected (6, {n}, {n}, 2)")
    if f.centre.shape != (3,):
        raise InputError(where, f"centre has shape {f.centre.shape}, expected (3,)")
    for name, arr in (("texels", f.texels), ("residuals", f.residuals), ("centre", f.centre)):
        if not np.isfinite(arr).all():
            raise InputError(where, f"{name} contain NaN or inf")
    if not (f.radius > 0 and math.isfinite(f.r_far) and f.r_far > f.radius and 0 <= f.r_near < f.r_far):
        raise InputError(
            where, f"inconsistent radii: radius {f.radius:.6g}, r_near {f.r_near:.6g}, r_far {f.r_far:.6g}"
        )
    if not (0.0 <= f.a0 <= 1.0 and 0.0 <= f.power < math.inf):
        raise InputError(where, f"a0 must be in [0, 1] and power >= 0, got {f.a0:.6g}, {f.power:.6g}")
    if (f.texels[..., _k.P_R0] < 0).any():
        raise InputError(where, "negative hull distances r0")
    if f.model not in MODELS:
        raise InputError(where, f"unknown model {f.model!r} (expected one of {', '.join(MODELS)})")
    if not (0.0 < f.d_min < f.d_max < math.inf):
        raise InputError(where, f"inconsistent radial layout: d_min {f.d_min:.6g}, d_max {f.d_max:.6g}")
    if f.model == "table":
        shape = None if f.table is None else f.table.shape
        if shape is None or len(shape) != 5 or shape[:3] != (6, n, n) or shape[3] < 2 or shape[4] != 4:
            raise InputError(where, f"table has shape {shape}, expected (6, {n}, {n}, M >= 2, 4)")
        if not np.isfinite(f.table).all():
            raise InputError(where, "table contains NaN or inf")


def load_field(path: str | Path) -> AOField:
    """Read a field written by :func:`save_field`; validate everything.

    Raises
    ------
    InputError
        One line naming the file: unreadable or not an npz, truncated, a missing key,
        a wrong dtype or shape, another format version, or inconsistent values.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            names = set(z.files)
            missing = [k for k in _KEYS if k not in names]
            if missing:
                raise InputError(path, f"not an aobake field file: missing {', '.join(missing)}")
            data = {k: z[k] for k in _KEYS}
            table = z["table"] if "table" in names else None
    except InputError:
        raise
    except FileNotFoundError:
        raise InputError(path, "no such file") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as exc:
        reason = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise InputError(path, f"not a readable field file ({reason})") from None
    version = data["format_version"]
    if version.shape != () or version.dtype.kind not in "iu":
        raise InputError(path, "format_version must be an integer scalar")
    if int(version) != FORMAT_VERSION:
        raise InputError(path, f"field format version {int(version)} is not supported (expected {FORMAT_VERSION})")
    res = data["resolution"]
    if res.shape != () or res.dtype.kind not in "iu" or int(res) < 1:
        raise InputError(path, "resolution must be a positive integer scalar")
    for k in ("texels", "residuals", "centre"):
        if data[k].dtype.kind != "f":
            raise InputError(path, f"{k} must be floating point, got {data[k].dtype}")
    if table is not None and table.dtype.kind != "f":
        raise InputError(path, f"table must be floating point, got {table.dtype}")
    for k in _SCALARS:
        if data[k].shape != () or data[k].dtype.kind not in "fiu":
            raise InputError(path, f"{k} must be a number")
    for k in _STRINGS:
        if data[k].shape != () or data[k].dtype.kind != "U":
            raise InputError(path, f"{k} must be a string")
    try:
        params = json.loads(str(data["params"]))
        if not isinstance(params, dict):
            raise ValueError
    except ValueError:
        raise InputError(path, "params is not a JSON object") from None
    f = AOField(
        texels=data["texels"].astype(np.float32),
        residuals=data["residuals"].astype(np.float32),
        centre=data["centre"].astype(np.float64),
        radius=float(data["radius"]),
        r_far=float(data["r_far"]),
        r_near=float(data["r_near"]),
        a0=float(data["a0"]),
        power=float(data["power"]),
        resolution=int(res),
        model=str(data["model"]),
        table=None if table is None or str(data["model"]) != "table" else table.astype(np.float32),
        d_min=float(data["d_min"]),
        d_max=float(data["d_max"]),
        params=params,
        occluder_name=str(data["occluder_name"]),
        occluder_hash=str(data["occluder_hash"]),
    )
    _validate(f, path)
    return f
