"""Validation and per-vertex geometry of aobake.mesh, from arrays (files: test_io_readers.py)."""

from __future__ import annotations

import numpy as np
import pytest

from aobake.errors import InputError
from aobake.mesh import (
    angle_weighted_normals,
    face_normals_and_areas,
    surface_from_arrays,
    vertex_areas,
)


def test_arrays_validated():
    with pytest.raises(
        InputError, match=r"^<memory>: 1 faces reference vertex -1 but the mesh has 3 vertices$"
    ):
        surface_from_arrays(np.eye(3), [[0, 1, -1]])
    with pytest.raises(InputError, match="no faces"):
        surface_from_arrays(np.eye(3), [])
    with pytest.raises(InputError, match="integer"):
        surface_from_arrays(np.eye(3), [[0, 1, 1.5]])


# -- per-vertex geometry -----------------------------------------------------------------


def test_needle_triangle_has_no_nan():
    positions = np.array([[0.0, 0.0, 0.0], [1e6, 0.0, 0.0], [1e6, 1e-9, 0.0]])
    faces = np.array([[0, 1, 2]])
    normals, areas = face_normals_and_areas(positions, faces)
    np.testing.assert_allclose(areas, [0.5e-3], rtol=1e-12)
    np.testing.assert_array_equal(normals, [[0.0, 0.0, 1.0]])
    np.testing.assert_allclose(vertex_areas(positions, faces), [0.5e-3 / 3] * 3, rtol=1e-12)


def test_collinear_triangle_is_zero_not_nan():
    positions = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]])
    normals, areas = face_normals_and_areas(positions, np.array([[0, 1, 2]]))
    np.testing.assert_array_equal(normals, np.zeros((1, 3)))
    np.testing.assert_array_equal(areas, [0.0])
    np.testing.assert_array_equal(
        angle_weighted_normals(positions, np.array([[0, 1, 2]])), np.zeros((3, 3))
    )


def test_vertex_areas_unit_square():
    positions = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [7, 7, 7]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    np.testing.assert_allclose(
        vertex_areas(positions, faces), [1 / 3, 1 / 6, 1 / 3, 1 / 6, 0.0], rtol=1e-15
    )


def test_cube_corner_normal_is_exact():
    import trimesh

    box = trimesh.creation.box(extents=[2.0, 3.0, 5.0])  # unequal faces: area weighting would tilt
    positions, faces = np.asarray(box.vertices), np.asarray(box.faces)
    normals = angle_weighted_normals(positions, faces)
    expected = np.sign(positions) / np.sqrt(3.0)
    np.testing.assert_allclose(normals, expected, atol=1e-15)
