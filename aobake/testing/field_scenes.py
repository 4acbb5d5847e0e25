"""Shared pieces of the AO-field tests: receivers on a plane, and small fields fitted on
the unit icosphere (each test module fits the ones it needs, once)."""

from __future__ import annotations

import numpy as np

from ..methods.fields import fit_field
from . import scenes

_BALL_FIT = dict(resolution=6, radial_samples=10)
#: name -> fit options of the small sphere fields
BALL_KINDS = {
    "raster": dict(sampler="raster", raster_size=48),
    "embree": dict(sampler="embree", n_rays=1024),
    "paper": dict(sampler="raster", raster_size=48, model="paper"),
    "table": dict(sampler="raster", raster_size=48, model="table"),
}


def ball():
    return scenes.sphere(1.0, 3)


def ball_fields(kinds=tuple(BALL_KINDS)) -> dict:
    """Fields of the unit icosphere at resolution 6, 10 radial samples, by kind."""
    surface = ball()
    return {k: fit_field(surface, **BALL_KINDS[k], **_BALL_FIT) for k in kinds}


def plane_receivers(height: float, half: float = 2.5, n: int = 9, z_axis: int = 2):
    t = np.linspace(-half, half, n)
    x, y = np.meshgrid(t, t, indexing="ij")
    p = np.zeros((x.size, 3))
    p[:, (z_axis + 1) % 3] = x.ravel()
    p[:, (z_axis + 2) % 3] = y.ravel()
    p[:, z_axis] = -height
    normals = np.zeros_like(p)
    normals[:, z_axis] = 1.0
    return p, normals
