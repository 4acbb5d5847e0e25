"""The fast paths of the PLY writer and the triangulation give the bytes and indices of
the general code they short-cut."""

from __future__ import annotations

import numpy as np
import pytest

from aobake.io import ply
from aobake.io.plyparse import PlyList, read_ply
from aobake.mesh import fan_triangulate


def _general_fan(counts, indices):
    """fan_triangulate's general path, for any polygon sizes."""
    counts = np.asarray(counts, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    starts = np.cumsum(counts) - counts
    n_tri = np.maximum(counts - 2, 0)
    first = np.repeat(starts, n_tri)
    k = np.arange(int(n_tri.sum())) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri) + 1
    return np.stack([indices[first], indices[first + k], indices[first + k + 1]], axis=1).reshape(-1, 3)


@pytest.mark.parametrize("sizes", [[3] * 7, [3, 4, 3], [3, 3, 2, 5], [4] * 3])
def test_fan_triangulate_matches_general(sizes):
    rng = np.random.default_rng(len(sizes))
    counts = np.array(sizes)
    indices = rng.integers(0, 100, size=int(counts.sum()))
    got = fan_triangulate(counts, indices)
    want = _general_fan(counts, indices)
    assert got.dtype == want.dtype and np.array_equal(got, want)
    got[:] = -1  # a fresh array: the caller may write to it
    assert (indices >= 0).all()


def _element(rng, count, list_counts):
    props = [("x", "<f4", None), ("flag", "|u1", None), ("vertex_indices", "<i4", "|u1"),
             ("d", ">f8", None), ("texcoord", "<f4", "<u2")]  # fmt: skip
    columns = {
        "x": rng.normal(size=count),
        "flag": rng.integers(0, 255, size=count).astype(np.float64),
        "vertex_indices": PlyList(np.asarray(list_counts[0]), rng.integers(0, 1000, size=int(np.sum(list_counts[0])))),
        "d": rng.normal(size=count),
        "texcoord": PlyList(np.asarray(list_counts[1]), rng.normal(size=int(np.sum(list_counts[1])))),
    }
    return props, columns


@pytest.mark.parametrize(
    "list_counts",
    [([3] * 5, [0] * 5), ([4] * 5, [2] * 5), ([3, 4, 3, 3, 3], [2] * 5), ([3] * 5, [0, 2, 0, 2, 2])],
    ids=["triangles", "quads", "mixed-faces", "mixed-texcoords"],
)
def test_fixed_rows_same_bytes_as_scatter(list_counts):
    rng = np.random.default_rng(1)
    props, columns = _element(rng, 5, list_counts)
    little = [(np.dtype(t).newbyteorder("<"), None if c is None else np.dtype(c).newbyteorder("<"))
              for _, t, c in props]  # fmt: skip
    want = ply._scattered_rows(5, props, little, columns)
    fixed = ply._fixed_rows(5, props, little, columns)
    varying = any(len(set(c)) > 1 for c in list_counts)
    assert (fixed is None) == varying
    assert ply._element_bytes(5, props, columns) == want
    if fixed is not None:
        assert fixed == want


def test_fixed_rows_empty_element():
    props = [("x", "<f4", None), ("vertex_indices", "<i4", "|u1")]
    columns = {"x": np.zeros(0), "vertex_indices": PlyList(np.zeros(0, dtype=np.int64), np.zeros(0))}
    assert ply._element_bytes(0, props, columns) == b""


@pytest.mark.parametrize("index_type", ["int", "uint", "ushort"])
def test_triangle_ply_shares_one_index_array_and_writes_back_same_bytes(tmp_path, index_type):
    # An all-triangle PLY: the surface's faces, its part's polygons and the kept face
    # list are one int64 array, the kept x y z views of the positions (no copies);
    # written back, each keeps its declared type and values.
    from aobake.io import load_mesh, write_bake

    rng = np.random.default_rng(7)
    pos = rng.normal(size=(40, 3)).astype("<f4")
    tri = rng.integers(0, 40, size=(60, 3))
    kind = {"int": "<i4", "uint": "<u4", "ushort": "<u2"}[index_type]
    rec = np.empty(len(tri), dtype=[("n", "u1"), ("i", kind, (3,))])
    rec["n"], rec["i"] = 3, tri
    header = (
        f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pos)}\nproperty float x\n"
        f"property float y\nproperty float z\nelement face {len(tri)}\n"
        f"property list uchar {index_type} vertex_indices\nend_header\n"
    )
    src = tmp_path / "in.ply"
    src.write_bytes(header.encode() + pos.tobytes() + rec.tobytes())
    s = load_mesh(src)
    kept = s.metadata["ply"].data.elements["face"].properties["vertex_indices"].values
    assert np.array_equal(s.faces, tri)
    assert np.shares_memory(s.faces, s.parts[0].face_vertex_indices)
    assert np.shares_memory(s.faces, kept)
    assert np.shares_memory(s.positions, s.metadata["ply"].data.elements["vertex"].properties["x"])
    counts = s.parts[0].face_vertex_counts
    assert counts.shape == (len(tri),) and counts.strides == (0,) and (counts == 3).all()
    out = tmp_path / "out.ply"
    write_bake(out, s, np.full(len(pos), 0.5))
    back = read_ply(out).elements["vertex"].properties
    for k, axis in enumerate("xyz"):
        assert back[axis].dtype == np.float32 and back[axis].tobytes() == pos[:, k].tobytes()
    body = out.read_bytes()
    assert f"property list uchar {index_type} vertex_indices" in body[:400].decode("ascii", "replace")
    assert body.endswith(rec.tobytes())
