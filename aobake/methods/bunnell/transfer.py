"""Bunnell's indirect light, first increment: the unshadowed disk-to-disk transfer of RGB
radiance between the disk method's vertex elements, brute force (docs/bunnell-light.md).

Numpy-facing; the sum is ``aobake.kernels.transfer.gather``.
"""

from __future__ import annotations

import math

import numpy as np

from ...kernels import transfer as _kt
from .elements import DiskElements


def outgoing_radiance(albedo, irradiance, emission=None) -> np.ndarray:
    """(n, 3) radiance a Lambertian vertex sends out: ``albedo irradiance / pi + emission``."""
    out = np.asarray(albedo, dtype=np.float64) * np.asarray(irradiance, dtype=np.float64) / math.pi
    if emission is not None:
        out = out + np.asarray(emission, dtype=np.float64)
    return np.ascontiguousarray(np.broadcast_to(out, np.shape(irradiance)), dtype=np.float64)


def transfer(points, normals, centres, disk_normals, areas, radiance, own=None) -> np.ndarray:
    """(n, 3) irradiance at each receiver (point, unit normal) from every emitting disk.

    Each disk of area ``A`` and radiance ``L`` adds ``pi L A cos_e cos_r / (pi r^2 + A)``
    (exact on a disk's axis), nothing from behind either side; no shadowing. ``own[j]``
    names the receiver disk j belongs to, which it does not light (default: none).
    """
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    normals = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3)
    centres = np.ascontiguousarray(centres, dtype=np.float64).reshape(-1, 3)
    disk_normals = np.ascontiguousarray(disk_normals, dtype=np.float64).reshape(-1, 3)
    areas = np.ascontiguousarray(areas, dtype=np.float64).reshape(-1)
    radiance = np.ascontiguousarray(radiance, dtype=np.float64).reshape(-1, 3)
    k = centres.shape[0]
    if normals.shape != points.shape or disk_normals.shape != centres.shape or areas.shape != (k,) or radiance.shape[0] != k:
        raise ValueError("transfer: receivers need (n, 3) points and normals; disks (k, 3) centres, normals, radiance and (k,) areas")
    own = np.full(k, -1, dtype=np.int64) if own is None else np.ascontiguousarray(own, dtype=np.int64).reshape(k)
    out = np.empty(points.shape)
    _kt.gather(points, normals, centres, disk_normals, areas, radiance, own, out)
    return out


def unshadowed_irradiance(elements: DiskElements, radiance) -> np.ndarray:
    """(n, 3) irradiance at every vertex from every other vertex's disk, without shadowing
    (the first pass of Bunnell's scheme).

    Parameters
    ----------
    elements : DiskElements
        The disk method's per-vertex elements (normalised coordinates: the transfer is
        dimensionless, so the result is in the radiance's units).
    radiance : (n, 3) float64 >= 0
        Outgoing radiance of each vertex (:func:`outgoing_radiance`).
    """
    radiance = np.asarray(radiance, dtype=np.float64)
    if radiance.shape != (elements.n_vertices, 3):
        raise ValueError(f"radiance must be ({elements.n_vertices}, 3), got {radiance.shape}")
    if not np.all(np.isfinite(radiance)) or np.any(radiance < 0.0):
        raise ValueError("radiance must be finite and >= 0")
    idx = elements.emitter_index
    idx = idx[np.any(radiance[idx] > 0.0, axis=1)]  # dark disks send nothing
    return transfer(
        elements.points,
        elements.normals,
        elements.positions[idx],
        elements.normals[idx],
        elements.areas[idx],
        radiance[idx],
        idx,
    )
