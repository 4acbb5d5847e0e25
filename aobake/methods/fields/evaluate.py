"""Evaluating ambient occlusion fields at receivers: one or several rigidly placed
occluders, combined as prod_k (1 - A_k); and the cap integral they end in.

Numpy-facing; the lookups run in ``aobake.kernels.field_eval`` (``_k.*``). Never prints.

References
----------
J. Kontkanen and S. Laine, "Ambient Occlusion Fields", Proc. I3D 2005, 41-48.
J. Snyder, "Area Light Sources for Real-Time Graphics", Microsoft Research TR-96-11 (1996).
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass

import numpy as np

from ..._types import AOArray, FloatArray
from ...checks import numba_threads
from ...errors import NumericalError
from ...kernels import cap as _cap
from ...kernels import field_eval as _k
from ...kernels import field_model as _model
from .field import AOField
from .layout import texel_anchors, unit

# Cap integral table for evaluation: several times faster than the closed form, with an
# error far below the field's own; the closed form builds it and stays public.
CAP_LUT = 256


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
    _cap.cap_occlusion_array(om, ct, out)
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
    out = np.zeros(f.texels.shape[:3] + (_model.N_EVAL,), dtype=np.float32)
    out[..., : _model.N_PARAMS] = f.texels
    out[..., _model.P_WX :] = unit(texel_anchors(f.resolution))
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
