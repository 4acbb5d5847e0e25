"""Where an AO field samples (aobake.methods.fields.layout): exact convex-hull distances."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aobake.mesh import surface_from_arrays
from aobake.methods.fields.layout import hull_distance, surface_centre
from aobake.testing import scenes

# --------------------------------------------------------------------------- convex hull


def exact_convex_distance(s, centre, dirs):
    """Ray exit distance through a convex mesh, face by face."""
    p = s.positions - centre
    f = s.faces
    n = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    off = np.einsum("ij,ij->i", n, p[f[:, 0]])
    n, off = n * np.sign(off)[:, None], np.abs(off)
    dn = dirs @ n.T
    return np.where(dn > 1e-12, off / np.where(dn > 1e-12, dn, 1.0), np.inf).min(axis=1)


@pytest.mark.parametrize(
    "surface",
    [scenes.box((1.0, 2.0, 3.0)), scenes.sphere(1.0, 2), scenes.random_convex(4, 2, scale=100.0)],
    ids=["box", "icosphere", "affine"],
)
def test_hull_distance_is_exact_on_convex_polyhedra(surface):
    centre = surface_centre(surface.positions, surface.faces)
    dirs = np.random.default_rng(5).normal(size=(300, 3))
    dirs = np.vstack([dirs, np.eye(3), -np.eye(3), [[1, 1, 1]]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    got = hull_distance(surface.positions, dirs, centre)
    np.testing.assert_allclose(got, exact_convex_distance(surface, centre, dirs), rtol=1e-10)


def test_hull_distance_of_a_nonconvex_mesh_is_its_hulls():
    # a box with a dent on top (a vertex pushed in): the hull is the box
    box = scenes.box((2.0, 2.0, 2.0))
    dented = np.vstack([box.positions, [[0.0, 0.0, 0.2]]])
    top = np.flatnonzero(np.isclose(box.positions[:, 2], 1.0))
    extra = np.array([[top[0], top[1], 8], [top[1], top[2], 8]])
    s = surface_from_arrays(dented, np.vstack([box.faces, extra]))
    dirs = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0]])
    got = hull_distance(s.positions, dirs, np.zeros(3))
    np.testing.assert_allclose(got, [1.0, math.hypot(0.1, 1.0)], rtol=1e-12)
