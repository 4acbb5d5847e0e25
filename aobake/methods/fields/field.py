"""The fitted ambient occlusion field as data: :class:`AOField` and what the evaluation
kernel reads from it.

An :class:`AOField` stores, per direction of a cube map around the occluder's centre,
seven scalars: a, b, c of the radial model den(r) = a r^2 + b r + c of Omega, the hull
distance r0 and the characteristic point C_o of the mean occluded direction
Y(r) = normalize(C_o - x).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..._types import FloatArray
from ...kernels import field_model as _k

#: Radial model name (``AOField.model``, the file's "model") -> kernel code.
MODEL_CODES = {"paper": _k.MODEL_PAPER, "cap": _k.MODEL_CAP, "table": _k.MODEL_TABLE}


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
    model : {"cap", "paper", "table"}
        How Omega depends on r (see :class:`~aobake.methods.fields.FieldOptions`).
    table : (6, R + 2, R + 2, M, 4) float32 or None
        The table model's knots: Omega and int V w dw at r0 + d_i.
    d_min, d_max : float
        The radial layout: d_i log-spaced from d_min to d_max
        (:func:`~aobake.methods.fields.layout.radial_layout`).
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
    model: str = "cap"
    table: np.ndarray | None = None
    d_min: float = 0.0
    d_max: float = 0.0
    params: dict = field(default_factory=dict)
    occluder_name: str = ""
    occluder_hash: str = ""
    #: Wall time of :func:`~aobake.methods.fields.fit_field` (0 for a loaded field; not saved).
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
        """(7,) float64: what ``kernels.field_eval.evaluate`` reads (see its docstring)."""
        knots = 0 if self.table is None else self.table.shape[3]
        per_log = (knots - 1) / math.log(self.d_max / self.d_min) if knots > 1 else 0.0
        return np.array(
            [self.r_far, self.r_near, self.a0, self.power, MODEL_CODES[self.model], self.d_min, per_log]
        )
