"""Helpers of the disk method's tests: small scenes, the passes with options and scheme
switches as keywords alike, and raw kernel sums (through the pass's private set-up)."""

from __future__ import annotations

import numpy as np

from ..constants import MEASURE_CODES
from ..mesh import surface_from_arrays
from ..methods import bunnell as B
from ..methods.bunnell import BunnellOptions
from ..methods.bunnell import passes as P
from ..progress import NullProgress
from .scenes import combine_meshes, ground_grid, icosphere, sphere_on_plane

#: Radius and height of the polar disk over the receiver (closed-form oracle).
R_DISK, H_DISK = 0.7, 1.3


def passes_of(elements, tree=None, **keywords):
    """``occlusion_passes`` with options and scheme switches as keywords alike."""
    return B.occlusion_passes(elements, tree, *B.settings(**keywords))



def polar_disk(radius, height, rings=24, sectors=96):
    """Disk at z = height facing down, as a polar grid (fine everywhere, unlike a fan)."""
    rad = np.linspace(0.0, radius, rings + 1)[1:]
    ang = np.linspace(0.0, 2 * np.pi, sectors, endpoint=False)
    rr, aa = np.meshgrid(rad, ang, indexing="ij")
    rim = np.c_[rr.ravel() * np.cos(aa.ravel()), rr.ravel() * np.sin(aa.ravel())]
    xy = np.vstack([[0.0, 0.0], rim])
    positions = np.c_[xy, np.full(len(xy), height)]
    idx = 1 + np.arange(rings * sectors).reshape(rings, sectors)
    nxt = np.roll(idx, -1, axis=1)
    faces = [np.c_[np.zeros(sectors, dtype=np.int64), nxt[0], idx[0]]]
    a, b, c, d = idx[:-1], nxt[:-1], nxt[1:], idx[1:]
    faces.append(np.c_[a.ravel(), d.ravel(), c.ravel()])
    faces.append(np.c_[a.ravel(), c.ravel(), b.ravel()])
    return positions, np.concatenate(faces).astype(np.int64)


def receiver_under_disk(normal=(0.0, 0.0, 1.0)):
    """Polar disk R = 0.7 at h = 1.3 facing down; the last vertex is an isolated receiver
    at the origin with the given normal (area 0: it receives, casts nothing)."""
    positions, faces = polar_disk(R_DISK, H_DISK)
    normals = np.zeros((len(positions) + 1, 3))
    normals[:-1, 2] = -1.0
    normals[-1] = normal
    positions = np.vstack([positions, [0.0, 0.0, 0.0]])
    return surface_from_arrays(positions, faces, normals)


def small_scene():
    """Sphere on a ground grid plus split vertices, a no-normal vertex and isolated ones."""
    s = sphere_on_plane(subdivisions=2, cells=12)
    p, f, n = s.positions, s.faces, s.normals
    # split copy of the first face (same positions, its own vertices and normals)
    extra_p = np.vstack([p[f[0]], [[0.0, 0.0, 2.0], p[5]]])
    extra_n = np.vstack([-n[f[0]], [[0, 0, 0], [0, 0, 1.0]]])  # flipped, none, isolated
    k = len(p)
    faces = np.vstack([f, [[k, k + 2, k + 1]]])
    return surface_from_arrays(np.vstack([p, extra_p]), faces, np.vstack([n, extra_n]))


DEFAULTS = BunnellOptions()


def kernel_sums(elements, tree, weights, *, measure="cosine", max_distance=None, near=DEFAULTS.near,
          theta=DEFAULTS.theta, cell_weights=None, directional=True):
    """Raw (front, back) kernel sums with given weights (brute force when tree is None)."""
    reach = np.inf if max_distance is None else max_distance / elements.scale
    job = P._Pass(elements, tree, theta, near, MEASURE_CODES[measure], reach, directional=directional)
    return job.sums(weights, NullProgress(), cell_weights)[0]


def balls_over_floor():
    """Two balls hovering over a floor (three layers; no contact, so receivers sit
    straight above their vertices as in the numpy reference)."""
    return combine_meshes(
        icosphere(1, center=(-1.1, 0.0, 0.2)), icosphere(1, center=(1.1, 0.0, 0.2)),
        ground_grid(3.0, 6, -1.0),
    )
