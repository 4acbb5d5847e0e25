"""The ground plane (``--ground auto|HEIGHT``): an infinite occluder perpendicular to the
up axis that every method honours and nothing receives on.

A point at height h above the plane sees it in the directions d with -d.up > 0, and
within a reach D only where the plane is nearer than D along d: -d.up >= h / D, a cone
about -up of half-angle alpha, cos(alpha) = h / D. What it occludes is that cone clipped
to the receiver's hemisphere: a spherical cap, so the closed forms here are exact.
Numpy only (the cosine measure's cap integral is ``kernels.cap``, imported on use).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import SettingError

AXES = {"X": 0, "Y": 1, "Z": 2}

#: What the plane reflects in a lit bake (linear RGB, all channels): the grey a
#: surface without a colour gets (:data:`aobake.shading.DEFAULT_ALBEDO`).
ALBEDO = 0.18

#: Vertices this far below the plane (relative to the mesh's extent along up) count as
#: on it: float rounding of a mesh exported "on the floor" is not a mistake.
BELOW_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Ground:
    """An occluding plane ``x[axis] = height`` (mesh units) facing +axis.

    Attributes
    ----------
    axis : int
        1 (Y up) or 2 (Z up).
    height : float
    """

    axis: int
    height: float

    def heights(self, points) -> np.ndarray:
        """(n,) height of each point above the plane, never below 0 (a point within
        rounding below it is on it)."""
        return np.maximum(np.asarray(points, dtype=np.float64)[:, self.axis] - self.height, 0.0)


def parse_ground(text) -> str | float:
    """``"auto"`` or a finite float from ``--ground``'s text; ValueError otherwise."""
    if isinstance(text, str) and text.strip().lower() == "auto":
        return "auto"
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ValueError(f"expected 'auto' or a height in mesh units, got {text!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"the height must be a finite number, got {text!r}")
    return value


def resolve_ground(spec, positions, up_axis: str, source=None) -> Ground | None:
    """The :class:`Ground` of ``spec`` (None, ``"auto"``, a height or a Ground) for a mesh.

    ``"auto"``: at the lowest vertex along ``up_axis``. A height above any vertex (beyond
    :data:`BELOW_TOLERANCE` of the mesh's extent) is a :class:`~aobake.errors.SettingError`
    (an InputError, exit 2 on the command line) naming ``source``: the plane would cut
    the mesh, and a receiver under it is undefined.
    """
    if spec is None:
        return None
    if isinstance(spec, Ground):
        axis, height = spec.axis, float(spec.height)
    else:
        value = parse_ground(spec)
        axis = AXES[str(up_axis).upper()]
        height = None if value == "auto" else float(value)
    along = np.asarray(positions, dtype=np.float64)[:, axis]
    lo, hi = float(along.min()), float(along.max())
    if height is None:
        return Ground(axis, lo)
    up = "XYZ"[axis]
    slack = BELOW_TOLERANCE * max(hi - lo, abs(hi), abs(lo), np.finfo(float).tiny)
    if height > hi + slack:
        raise SettingError(source, f"--ground {height:g} is above the mesh's highest point {hi:g} (up {up})")
    if height > lo + slack:
        below = int((along < height - slack).sum())
        raise SettingError(
            source,
            f"--ground {height:g} is above the mesh's lowest point {lo:g} (up {up}): "
            f"{below} vertices below the plane",
        )
    return Ground(axis, height)


def reach_cosines(heights, max_distance) -> np.ndarray:
    """cos(alpha) = h / D of the cone of directions in which the plane is within reach
    (0: the whole lower hemisphere; >= 1: out of reach)."""
    h = np.asarray(heights, dtype=np.float64)
    if max_distance is None:
        return np.zeros_like(h)
    return h / float(max_distance)


def plane_occlusion(heights, normals, axis: int, measure: str = "cosine", max_distance=None) -> np.ndarray:
    """(n,) occlusion A of the plane at points ``heights`` above it with unit ``normals``.

    Cosine measure: the cosine-weighted integral of the cap about -up (Snyder's closed
    form; unbounded it is (1 - n.up) / 2). Uniform: the cap's solid angle inside the
    hemisphere over 2 pi (two caps' intersection; unbounded acos(n.up) / pi). A zero
    normal sees the whole sphere: the cap's share of it, (1 - cos alpha) / 2, both measures.
    """
    normals = np.asarray(normals, dtype=np.float64)
    cos_a = np.clip(reach_cosines(heights, max_distance), 0.0, 1.0)
    ct = np.clip(-normals[:, axis], -1.0, 1.0)  # cos of the angle between n and -up
    has_normal = np.any(normals != 0.0, axis=1)
    if measure == "cosine":
        from .kernels.cap import cap_occlusion_array

        out = np.zeros(ct.shape[0])
        omega = np.ascontiguousarray(2.0 * math.pi * (1.0 - cos_a))
        cap_occlusion_array(omega, np.ascontiguousarray(ct), out)
    else:
        out = _cap_in_hemisphere(cos_a, ct) / (2.0 * math.pi)
    out = np.where(has_normal, out, 0.5 * (1.0 - cos_a))
    return np.clip(out, 0.0, 1.0)


def _cap_in_hemisphere(cos_a, ct) -> np.ndarray:
    """Solid angle of a cap (cos half-angle ``cos_a`` in [0, 1]) inside a hemisphere whose
    pole is at cos = ``ct`` from the cap's axis (the two-cap intersection formula with one
    cap a hemisphere)."""
    cos_a = np.asarray(cos_a, dtype=np.float64)
    ct = np.asarray(ct, dtype=np.float64)
    sin_a = np.sqrt(np.maximum(1.0 - cos_a * cos_a, 0.0))
    st = np.sqrt(np.maximum(1.0 - ct * ct, 0.0))
    cap = 2.0 * math.pi * (1.0 - cos_a)
    inside = ct >= sin_a  # the whole cap above the horizon
    outside = ct <= -sin_a
    with np.errstate(divide="ignore", invalid="ignore"):
        a1 = np.arccos(np.clip(ct / sin_a, -1.0, 1.0))
        a2 = np.arccos(np.clip(-ct * cos_a / (st * sin_a), -1.0, 1.0))
        part = 2.0 * (math.pi - a1 - cos_a * a2)
    part = np.where(np.isfinite(part), part, 0.0)
    return np.where(inside, cap, np.where(outside, 0.0, np.clip(part, 0.0, cap)))
