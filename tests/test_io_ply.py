"""aobake.io.ply: the bake writer (read back with independent parsers: plyfile, trimesh),
reading ``ao`` back, and write_bake/read_bake for PLY and .npy. Mesh reading is in
tests/test_io_readers.py, the parser in tests/test_io_plyparse.py."""

from __future__ import annotations

import os

import numpy as np
import pytest
import trimesh
from plyfile import PlyData

from aobake.errors import InputError, NumericalError, OutputError
from aobake.io import ply as io_ply
from aobake.io import read_bake, write_bake
from aobake.io.ply import read_ao_ply, write_ply
from aobake.mesh import surface_from_arrays


def _mesh():
    """Two triangles plus a duplicate of vertex 0 (used) and an unreferenced vertex."""
    positions = np.array(
        [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0],  # duplicate of vertex 0, referenced by the second face
            [5.0, 5.0, 5.0],  # unreferenced
        ]
    )
    faces = np.array([[0, 1, 2], [4, 2, 3]])
    normals = np.tile([0.0, 0.0, 1.0], (6, 1))
    ao = np.array([0.0, 0.1, 0.5, 0.75, 0.3333333333, 1.0])
    return positions, faces, normals, ao


def _listing(directory):
    return sorted(p.name for p in directory.iterdir())


def test_plyfile_round_trip(tmp_path):
    positions, faces, normals, ao = _mesh()
    out = tmp_path / "bake.ply"
    write_ply(
        out, positions, faces, ao, normals=normals, color=True, comments=["aobake method=test"]
    )
    ply = PlyData.read(str(out))
    assert ply.text is False and ply.byte_order == "<"
    assert ply.comments == ["aobake method=test"]
    vertex = ply["vertex"].data
    assert len(vertex) == 6
    np.testing.assert_array_equal(
        np.column_stack([vertex["x"], vertex["y"], vertex["z"]]), positions
    )
    np.testing.assert_array_equal(
        np.column_stack([vertex["nx"], vertex["ny"], vertex["nz"]]), normals
    )
    assert vertex["ao"].dtype == np.float32
    np.testing.assert_array_equal(vertex["ao"], ao.astype(np.float32))
    np.testing.assert_array_equal(vertex["quality"], ao.astype(np.float32))
    # sRGB-encoded (IEC 61966-2-1), by hand: 1.055 * 0.5 ** (1 / 2.4) - 0.055 = 0.7354 -> 188
    expected_grey = np.array([0, 89, 188, 225, 156, 255], dtype=np.uint8)
    for channel in ("red", "green", "blue"):
        assert vertex[channel].dtype == np.uint8
        np.testing.assert_array_equal(vertex[channel], expected_grey)
    face = np.stack(ply["face"].data["vertex_indices"])
    np.testing.assert_array_equal(face, faces)


def test_property_layout_without_options(tmp_path):
    positions, faces, _, ao = _mesh()
    out = tmp_path / "plain.ply"
    write_ply(out, positions, faces, ao)
    names = [p.name for p in PlyData.read(str(out))["vertex"].properties]
    assert names == ["x", "y", "z", "ao", "quality"]


def test_trimesh_round_trip_keeps_order_duplicates_and_unreferenced(tmp_path):
    positions, faces, normals, ao = _mesh()
    out = tmp_path / "bake.ply"
    write_ply(out, positions, faces, ao, normals=normals, color=True)
    mesh = trimesh.load(out, process=False)
    np.testing.assert_array_equal(mesh.vertices, positions)
    np.testing.assert_array_equal(mesh.faces, faces)
    raw = mesh.metadata["_ply_raw"]["vertex"]["data"]
    assert raw["ao"].dtype == np.float32
    np.testing.assert_array_equal(raw["ao"], ao.astype(np.float32))
    np.testing.assert_array_equal(raw["quality"], ao.astype(np.float32))


def test_read_ao_ply_round_trip(tmp_path):
    positions, faces, normals, ao = _mesh()
    out = tmp_path / "bake.ply"
    write_ply(out, positions, faces, ao, normals=normals)
    got = read_ao_ply(out)
    assert got.dtype == np.float64 and got.shape == (6,)
    np.testing.assert_array_equal(got, ao.astype(np.float32).astype(np.float64))


def test_float64_positions_are_written_as_float32(tmp_path):
    positions, faces, _, ao = _mesh()
    positions = positions + 0.1  # not representable exactly in float32
    out = tmp_path / "f32.ply"
    write_ply(out, positions, faces, ao)
    vertex = PlyData.read(str(out))["vertex"].data
    assert vertex["x"].dtype == np.float32
    np.testing.assert_array_equal(vertex["x"], positions[:, 0].astype(np.float32))


def test_read_ascii_and_big_endian_from_other_tools(tmp_path):
    ascii_ply = tmp_path / "meshlab.ply"
    ascii_ply.write_text(
        "ply\nformat ascii 1.0\ncomment from another tool\nelement vertex 3\n"
        "property float x\nproperty float y\nproperty float z\nproperty float quality\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0 0.25\n1 0 0 0.5\n0 1 0 1\n3 0 1 2\n"
    )
    np.testing.assert_array_equal(read_ao_ply(ascii_ply), [0.25, 0.5, 1.0])
    # An element with lists before the vertices, and a list inside the vertex element.
    odd = tmp_path / "odd.ply"
    odd.write_text(
        "ply\nformat ascii 1.0\nelement camera 1\nproperty list uchar float params\n"
        "element vertex 2\nproperty list uchar int tags\nproperty double ao\n"
        "end_header\n2 1.5 2.5\n1 7 0.125\n0 0.875\n"
    )
    np.testing.assert_array_equal(read_ao_ply(odd), [0.125, 0.875])
    big = tmp_path / "big.ply"
    vertex = np.array([(0.0, 0.25), (1.0, 0.75)], dtype=[("x", ">f4"), ("ao", ">f8")])
    big.write_bytes(
        b"ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty float x\n"
        b"property double ao\nend_header\n" + vertex.tobytes()
    )
    np.testing.assert_array_equal(read_ao_ply(big), [0.25, 0.75])


def test_read_binary_with_lists_before_vertices(tmp_path):
    path = tmp_path / "lists.ply"
    head = (
        b"ply\nformat binary_little_endian 1.0\nelement blob 2\nproperty list uchar short v\n"
        b"element vertex 2\nproperty float ao\nend_header\n"
    )
    blob = bytes([1]) + np.int16(5).tobytes() + bytes([2]) + np.array([1, 2], "<i2").tobytes()
    path.write_bytes(head + blob + np.array([0.5, 0.25], "<f4").tobytes())
    np.testing.assert_array_equal(read_ao_ply(path), [0.5, 0.25])


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "in.ply: file not found"),
        (b"\x00\x01garbage" * 10, "in.ply: cannot read as PLY: not a PLY file (no 'ply' magic)"),
        (
            # the header is checked first: the missing property is reported, not the body
            b"ply\nformat binary_little_endian 1.0\nelement vertex 1\n"
            b"property float x\nproperty float y\nend_header\n",
            "in.ply: PLY vertices have no 'ao' or 'quality' property (found: x, y)",
        ),
        (
            b"ply\nformat ascii 1.0\nelement face 0\nend_header\n",
            "in.ply: PLY has no vertex element",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list uchar float ao\n"
            b"end_header\n1 0.5\n",
            "in.ply: PLY vertex property 'ao' is a list, not one value per vertex",
        ),
        (
            b"ply\nformat binary_little_endian 1.0\nelement vertex 4\n"
            b"property float ao\nend_header\n\x00\x00",
            "in.ply: cannot read as PLY: file ends before its 4 vertex elements (truncated)",
        ),
    ],
)
def test_read_errors_are_one_line_input_errors(tmp_path, content, message):
    path = tmp_path / "in.ply"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InputError) as info:
        read_ao_ply(path)
    assert str(info.value) == message


@pytest.mark.parametrize("bad", [np.nan, np.inf, -0.01, 1.5])
def test_bad_ao_raises_before_anything_is_created(tmp_path, bad):
    positions, faces, _, ao = _mesh()
    ao = ao.copy()
    ao[2] = bad
    with pytest.raises(NumericalError):
        write_ply(tmp_path / "bad.ply", positions, faces, ao)
    assert _listing(tmp_path) == []


def test_wrong_ao_length_raises(tmp_path):
    positions, faces, _, ao = _mesh()
    with pytest.raises(NumericalError, match="6 vertices"):
        write_ply(tmp_path / "bad.ply", positions, faces, ao[:-1])
    assert _listing(tmp_path) == []


def test_face_index_out_of_range_is_input_error(tmp_path):
    positions, faces, _, ao = _mesh()
    with pytest.raises(InputError, match="reference vertex 6 but the mesh has 6 vertices"):
        write_ply(tmp_path / "bad.ply", positions, faces + 2, ao)
    assert _listing(tmp_path) == []


def test_failure_midway_leaves_nothing(tmp_path, monkeypatch):
    positions, faces, _, ao = _mesh()
    out = tmp_path / "bake.ply"
    calls = []
    real_open = open

    class Exploding:
        """A file whose second write (the vertex block) fails, after the header is out."""

        def __init__(self, fh):
            self.fh = fh

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

        def write(self, data):
            calls.append(len(data))
            if len(calls) == 2:
                raise RuntimeError("disk vanished")
            return self.fh.write(data)

    monkeypatch.setattr(
        io_ply, "open", lambda p, mode: Exploding(real_open(p, mode)), raising=False
    )
    with pytest.raises(RuntimeError, match="disk vanished"):
        write_ply(out, positions, faces, ao)
    assert len(calls) == 2
    assert _listing(tmp_path) == []


def test_failure_keeps_previous_output(tmp_path, monkeypatch):
    positions, faces, _, ao = _mesh()
    out = tmp_path / "bake.ply"
    write_ply(out, positions, faces, ao)
    before = out.read_bytes()

    def boom(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(io_ply, "open", boom, raising=False)
    with pytest.raises(OutputError, match="No space left"):
        write_ply(out, positions, faces, np.zeros(6))
    assert out.read_bytes() == before
    assert _listing(tmp_path) == ["bake.ply"]


def test_missing_directory_is_output_error(tmp_path):
    positions, faces, _, ao = _mesh()
    with pytest.raises(OutputError, match="does not exist"):
        write_ply(tmp_path / "nope" / "bake.ply", positions, faces, ao)


@pytest.mark.skipif(
    os.name != "posix" or os.geteuid() == 0, reason="root ignores directory permissions"
)
def test_unwritable_directory_is_output_error(tmp_path):
    positions, faces, _, ao = _mesh()
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        with pytest.raises(OutputError, match="not writable"):
            write_ply(locked / "bake.ply", positions, faces, ao)
    finally:
        locked.chmod(0o700)


def test_directory_reported_unwritable_is_output_error(tmp_path, monkeypatch):
    # Runs as root too (where chmod does not lock a directory): the access check itself.
    import aobake.io.common

    positions, faces, _, ao = _mesh()
    monkeypatch.setattr(aobake.io.common.os, "access", lambda path, mode: False)
    with pytest.raises(OutputError, match="not writable"):
        write_ply(tmp_path / "bake.ply", positions, faces, ao)
    assert _listing(tmp_path) == []


def test_output_path_is_a_directory(tmp_path):
    positions, faces, _, ao = _mesh()
    (tmp_path / "dir.ply").mkdir()
    with pytest.raises(OutputError, match="is a directory"):
        write_ply(tmp_path / "dir.ply", positions, faces, ao)


def test_same_input_gives_identical_bytes(tmp_path):
    positions, faces, normals, ao = _mesh()
    write_ply(tmp_path / "a.ply", positions, faces, ao, normals=normals, color=True)
    write_ply(tmp_path / "b.ply", positions, faces, ao, normals=normals, color=True)
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()


def test_write_bake_and_read_bake_ply(tmp_path):
    positions, faces, normals, ao = _mesh()
    surface = surface_from_arrays(positions, faces, normals)
    out = tmp_path / "bake.ply"
    write_bake(out, surface, ao, color=True, custom_data={"method": "embree", "seed": 3})
    ply = PlyData.read(str(out))
    assert ply.comments == [
        "aobake method=embree", "aobake seed=3", "aobake up_axis=Y", "aobake meters_per_unit=1"
    ]
    np.testing.assert_array_equal(read_bake(out, n_vertices=6), ao.astype(np.float32))
    with pytest.raises(InputError, match="has 6 ao values but the mesh has 7 vertices"):
        read_bake(out, n_vertices=7)
    with pytest.raises(NumericalError, match="6 vertices"):
        write_bake(tmp_path / "short.ply", surface, ao[:3])
    assert not (tmp_path / "short.ply").exists()


def test_read_bake_npy(tmp_path):
    good = tmp_path / "ao.npy"
    np.save(good, np.array([0.5, 1.0], dtype=np.float32))
    got = read_bake(good)
    assert got.dtype == np.float64
    np.testing.assert_array_equal(got, [0.5, 1.0])
    bad = tmp_path / "bad.npy"
    np.save(bad, np.zeros((2, 2)))
    with pytest.raises(InputError, match="expected a 1-D float array"):
        read_bake(bad)
    pickled = tmp_path / "obj.npy"
    np.save(pickled, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(InputError, match="obj.npy"):
        read_bake(pickled)
    with pytest.raises(InputError, match="file not found"):
        read_bake(tmp_path / "missing.npy")
    with pytest.raises(InputError, match="unsupported AO file suffix"):
        read_bake(tmp_path / "ao.txt")
