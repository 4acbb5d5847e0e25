"""Fitting an ambient occlusion field around a rigid occluder: lay out the samples, measure
Omega and Y there (raster or Embree sampler), fit the 7 scalars of every texel.

Numpy-facing; the fits run in ``aobake.kernels.field_fit`` (``_k.*``). Never prints.

References
----------
J. Kontkanen and S. Laine, "Ambient Occlusion Fields", Proc. I3D 2005, 41-48.
"""

from __future__ import annotations

import hashlib
import math
import time

import numba
import numpy as np

from ..._types import FloatArray
from ...checks import numba_threads
from ...errors import InputError, NumericalError
from ...kernels import field_fit as _k
from ...kernels import field_model as _model
from ...kernels import hull as _hull
from ...mesh import Surface
from ...options import build
from ...progress import NullProgress, Progress
from ...tracing import split, trace_chunks
from .field import MODEL_CODES, AOField
from .fileformat import validate_field
from .layout import (
    face_tangents,
    quadrature_weights,
    radial_layout,
    support_points,
    surface_centre,
    texel_anchors,
    unit,
)
from .options import R_FAR_FACTOR, FieldOptions
from .raster import raster_occlusion
from .rays import footprint_samples

# The fade to zero starts at R_NEAR_FRACTION * r_far (smoothstep to r_far).
R_NEAR_FRACTION = 0.5
# Inside the hull A is blended towards A0 with t = (r / r0)^HULL_POWER: the centre of a
# solid occluder is fully occluded (A0 = 1); the power keeps the model's value near the
# hull, where receivers touch the occluder.
A0 = 1.0
HULL_POWER = 2.0
# Levenberg-Marquardt iterations: Omega in its own space after the linear fit, C_o.
OMEGA_ITERS = 8
CENTRE_ITERS = 20
# Y weights q_i (Omega_i / max)^Y_POWER: the AO error of a direction error scales with
# Omega (the quadrature weights q_i: layout.quadrature_weights).
Y_POWER = 2.0
# Sample points per raster call: progress and memory only.
_RASTER_CHUNK = 2048
# Texels per fit_texels call (one task of a worker thread).
_FIT_TASK = 32


def fit_kernel():
    """The texel fit's kernel and arguments of the types :func:`fit_field` passes it, for
    :mod:`aobake.precompile` to compile it in a helper process on a cold cache."""
    z = np.zeros
    return _k.fit_texels, (z((1, 2, 2)), z((1, 2, 4)), z((1, 3)), z(1), 2.0, z(4), z((1, _model.N_PARAMS)), z((1, 2)))


def occluder_hash(positions: FloatArray, faces) -> str:
    """SHA-256 (hex) of the occluder's float64 positions and int64 faces."""
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(positions, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    return digest.hexdigest()


def fit_field(
    surface: Surface,
    options: FieldOptions | None = None,
    *,
    progress: Progress | None = None,
    **changes,
) -> AOField:
    """Fit an ambient occlusion field around a rigid occluder.

    Parameters
    ----------
    surface : Surface
        The occluder (its triangles; either side occludes).
    options : FieldOptions, optional
        ``sampler``, ``resolution``, ``radial_samples``, ``raster_size``, ``n_rays``,
        ``r_far``, ``model``, ``prefilter``, ``seed``, ``threads`` (see
        :class:`FieldOptions`); keywords override them: ``fit_field(surface,
        resolution=8)``.
    progress : Progress, optional

    Returns
    -------
    AOField

    Raises
    ------
    ValueError
        An unknown sampler or model, or a count out of range.
    TypeError
        An unknown option.
    InputError
        ``r_far`` does not exceed the occluder's bounding radius, or the occluder has no
        extent.

    Notes
    -----
    Layout: the centre is the surface's area-weighted centroid; per texel direction w,
    r0 is the exact distance to the convex hull (:func:`~.layout.hull_distance`; the
    largest over the footprint when prefiltered) and the M samples sit at r0 + d_i with
    d_i log-spaced from 1e-3 bounding radii to r_far (:func:`~.layout.radial_layout`),
    so the contact region gets half of them.

    Fits per texel (Kontkanen & Laine 2005), with quadrature weights q_i = (the sample's
    share of r) x r_i, the room each sample stands for on a receiving plane
    (:func:`~.layout.quadrature_weights`):

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
    (Omega = 0). Residuals use the same weights.
    """
    t0 = time.perf_counter()
    opts = build(FieldOptions, options, **changes)
    from ... import precompile

    precompile.start("field-fit", threads=opts.threads)  # a cold cache: the fit's kernel compiles in a helper meanwhile (the CLI)
    sampler, model, res = opts.sampler, opts.model, opts.resolution
    radial_samples, prefilter = opts.radial_samples, opts.prefilter
    progress = progress or NullProgress()

    positions = np.ascontiguousarray(surface.positions, dtype=np.float64)
    faces = np.ascontiguousarray(surface.faces, dtype=np.int64)
    centre = surface_centre(positions, faces)
    local = np.ascontiguousarray(positions - centre)
    radius = float(np.linalg.norm(local, axis=1).max())
    if not radius > 0.0:
        raise InputError(surface.source, "occluder has no extent (all vertices coincide)")
    r_far = R_FAR_FACTOR * radius if opts.r_far is None else float(opts.r_far)
    if not (math.isfinite(r_far) and r_far > radius):
        raise InputError(surface.source, f"r_far {r_far:.6g} must exceed the occluder's bounding radius {radius:.6g}")

    n_side = res + 2
    anchors = texel_anchors(res)  # (6, P, P, 3)
    tangents = face_tangents(res)  # (6, P, P, 6)
    dirs = unit(anchors).reshape(-1, 3)
    n_tex = dirs.shape[0]

    with numba_threads(opts.threads):
        # r0: hull distance, the largest over the footprint when it is prefiltered, so
        # no sample of a texel falls inside the hull
        candidates = support_points(local)
        offsets = [(0.0, 0.0)] if prefilter == 1 else [(a, b) for a in (-0.5, 0.0, 0.5) for b in (-0.5, 0.0, 0.5)]
        flat_anchor = anchors.reshape(-1, 3)
        flat_tan = tangents.reshape(-1, 6)
        r0 = np.zeros(n_tex)
        for a, b in offsets:
            q = np.ascontiguousarray(unit(flat_anchor + a * flat_tan[:, :3] + b * flat_tan[:, 3:]))
            d = np.zeros(n_tex)
            _hull.hull_distances(q, candidates, local, d)
            r0 = np.maximum(r0, d)
        radii, d_min, d_max = radial_layout(r0, r_far, radius, radial_samples)  # (T, M)

        n_pts = n_tex * radial_samples
        if sampler == "raster":
            sub = (np.arange(prefilter) + 0.5) / prefilter - 0.5
            subs = [(a, b) for a in sub for b in sub]
            progress.start(n_pts * len(subs), f"field (raster {opts.raster_size})")
            samples = np.zeros((n_tex, radial_samples, 4))
            for a, b in subs:
                q = unit(flat_anchor + a * flat_tan[:, :3] + b * flat_tan[:, 3:])
                pts = (centre + radii[:, :, None] * q[:, None, :]).reshape(-1, 3)
                for s in range(0, n_pts, _RASTER_CHUNK):
                    om, vec = raster_occlusion(positions, faces, pts[s : s + _RASTER_CHUNK], size=opts.raster_size)
                    block = samples.reshape(-1, 4)[s : s + _RASTER_CHUNK]
                    block[:, 0] += om
                    block[:, 1:] += vec
                    progress.advance(om.shape[0])
            samples /= len(subs)
        else:
            progress.start(n_pts, f"field (embree {opts.n_rays} rays)")
            tan = flat_tan if prefilter > 1 else np.zeros_like(flat_tan)
            geometry = (
                np.repeat(flat_anchor, radial_samples, axis=0),
                np.repeat(tan, radial_samples, axis=0),
                radii.reshape(-1),
                centre,
            )
            samples = footprint_samples(
                positions, faces, geometry, n_rays=opts.n_rays, seed=opts.seed, threads=opts.threads, progress=progress
            ).reshape(n_tex, radial_samples, 4)
        progress.finish()

        params = np.zeros((n_tex, _model.N_PARAMS))
        resid = np.zeros((n_tex, 2))
        fit_model = _model.MODEL_CAP if model == "table" else MODEL_CODES[model]
        settings = np.array([OMEGA_ITERS, CENTRE_ITERS, Y_POWER, fit_model], dtype=np.float64)
        radial = np.ascontiguousarray(np.stack([radii, quadrature_weights(radii, r_far)], axis=-1))
        samples = np.ascontiguousarray(samples)
        dirs = np.ascontiguousarray(dirs)

        def fit(index: np.ndarray) -> int:
            s, e = int(index[0]), int(index[-1]) + 1
            _k.fit_texels(radial[s:e], samples[s:e], dirs[s:e], r0[s:e], r_far, settings, params[s:e],
                          resid[s:e])
            return e - s

        # each texel is fitted on its own: the result does not depend on the threads
        precompile.wait("field-fit")
        trace_chunks(split(np.arange(n_tex), _FIT_TASK), fit, threads=numba.get_num_threads(),
                     progress=NullProgress())
    if not (np.isfinite(params).all() and np.isfinite(resid).all()):
        raise NumericalError(f"{surface.source}: field fit produced non-finite parameters")
    # the file's record of the fit ("rays", not n_rays: the format's key)
    record = {"sampler": sampler, "radial_samples": radial_samples, "prefilter": prefilter}
    if sampler == "raster":
        record["raster_size"] = opts.raster_size
    else:
        record.update(rays=opts.n_rays, seed=opts.seed)
    out = AOField(
        texels=params.astype(np.float32).reshape(6, n_side, n_side, _model.N_PARAMS),
        residuals=resid.astype(np.float32).reshape(6, n_side, n_side, 2),
        centre=centre,
        radius=radius,
        r_far=r_far,
        r_near=R_NEAR_FRACTION * r_far,
        a0=A0,
        power=HULL_POWER,
        resolution=res,
        model=model,
        table=samples.astype(np.float32).reshape(6, n_side, n_side, radial_samples, 4) if model == "table" else None,
        d_min=d_min,
        d_max=d_max,
        params=record,
        occluder_name=surface.source,
        occluder_hash=occluder_hash(positions, faces),
        seconds=time.perf_counter() - t0,
    )
    validate_field(out, surface.source)
    return out
