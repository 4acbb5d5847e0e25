"""Angle-weighted normals from the numba kernels are bit for bit the numpy formulation
they replaced (kept here as the reference)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from aobake.constants import NORMAL_EPS
from aobake.mesh import angle_weighted_normals, normalize_rows
from aobake.testing import scenes

DATA = Path(__file__).resolve().parent.parent / "data"


def numpy_normals(positions, faces):
    """The former implementation: numpy cross/norm/einsum/arccos and np.add.at."""
    n = positions.shape[0]
    out = np.zeros((n, 3))
    if faces.shape[0] == 0:
        return out
    tri = positions[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(cross, axis=1)
    fn = np.zeros_like(cross)
    ok = length > 0.0
    fn[ok] = cross[ok] / length[ok, None]
    for k in range(3):
        a = tri[:, (k + 1) % 3] - tri[:, k]
        b = tri[:, (k + 2) % 3] - tri[:, k]
        la = np.linalg.norm(a, axis=1)
        lb = np.linalg.norm(b, axis=1)
        denom = la * lb
        cos = np.divide(np.einsum("ij,ij->i", a, b), denom, out=np.zeros_like(denom), where=denom > 0)
        angle = np.arccos(np.clip(cos, -1.0, 1.0))
        np.add.at(out, faces[:, k], fn * angle[:, None])
    return numpy_normalize(out)


def numpy_normalize(v):
    """The former normalize_rows (a zeroed copy filled where the length passes)."""
    length = np.linalg.norm(v, axis=1)
    out = np.zeros_like(v)
    ok = length > NORMAL_EPS
    out[ok] = v[ok] / length[ok, None]
    return out


def test_normalize_rows_same_bits_and_input_kept():
    # in-place division where the length passes: the former zeroed copy, bit for bit
    rng = np.random.default_rng(4)
    v = rng.normal(size=(3000, 3)) * 10.0 ** rng.integers(-12, 12, size=(3000, 1))
    v[::7] = 0.0
    v[::11] *= 1e-300
    v[5] = [-0.0, 0.0, -0.0]
    keep = v.copy()
    got = normalize_rows(v)
    assert got.tobytes() == numpy_normalize(keep).tobytes()
    assert v.tobytes() == keep.tobytes()
    assert (np.linalg.norm(got, axis=1) == 0).sum() >= 3000 // 7


def assert_same_bits(positions, faces):
    got = angle_weighted_normals(positions, faces)
    want = numpy_normals(positions, faces)
    assert got.dtype == want.dtype and got.shape == want.shape
    assert got.tobytes() == want.tobytes(), f"{np.sum(got != want)} values differ"


def random_mesh(rng, n, m, scale=1.0, offset=0.0):
    positions = rng.normal(size=(n, 3)) * scale + offset
    faces = rng.integers(0, n, size=(m, 3))
    return positions, faces


@pytest.mark.parametrize("seed", range(6))
def test_random_soups_same_bits(seed):
    # shared vertices (many corners per vertex: the order of the sums matters),
    # repeated indices (zero-area faces, zero-length edges) and unreferenced vertices
    rng = np.random.default_rng(seed)
    scale, offset = [(1.0, 0.0), (1e-6, 0.0), (1e3, 1e6), (1.0, -3.0), (1e8, 0.0), (0.1, 5.0)][seed]
    positions, faces = random_mesh(rng, 300, 2000, scale, offset)
    faces[:50, 1] = faces[:50, 0]  # degenerate: two corners at one vertex
    faces[50:60] = faces[50:60, :1]  # all three corners at one vertex
    assert_same_bits(positions, faces)


def test_needles_and_flat_faces_same_bits():
    rng = np.random.default_rng(7)
    positions, faces = random_mesh(rng, 200, 800)
    positions[:100, 2] = 0.0  # flat triangles among them (normals that cancel)
    positions[100:150] = positions[:50] + 1e-12 * rng.normal(size=(50, 3))  # needles
    assert_same_bits(positions, faces)


@pytest.mark.parametrize(
    "surface",
    [
        lambda: scenes.sphere_on_ground(0.5, 3, cells=20)[0],
        lambda: scenes.box(),
        lambda: scenes.voxel_sponge(),
        lambda: scenes.spheres_in_block(subdivisions=2, cells=9),
    ],
    ids=["sphere_on_ground", "box", "sponge", "spheres_in_block"],
)
def test_scenes_same_bits(surface):
    s = surface()
    assert_same_bits(s.positions, s.faces)


@pytest.mark.parametrize("name", ["bunny", "box_stack", "sphere_on_ground"])
def test_bundled_meshes_same_bits(name):
    from aobake.io import load_mesh

    s = load_mesh(DATA / f"{name}.ply")
    assert_same_bits(s.positions, s.faces)


def test_int32_faces_and_no_faces():
    rng = np.random.default_rng(3)
    positions, faces = random_mesh(rng, 50, 80)
    assert angle_weighted_normals(positions, faces.astype(np.int32)).tobytes() == numpy_normals(positions, faces).tobytes()
    assert not angle_weighted_normals(positions, np.zeros((0, 3), dtype=np.int64)).any()


def test_out_of_range_indices_rejected():
    with pytest.raises(ValueError, match="outside"):
        angle_weighted_normals(np.zeros((3, 3)), np.array([[0, 1, 3]]))
