"""The PLY parser (aobake.io.plyparse): three encodings, any elements, list properties of
any integer count type, and one-line errors for truncated bodies and bad headers.

Inputs are written by plyfile (an independent writer) or spelled out byte by byte.
"""

from __future__ import annotations

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from aobake.errors import InputError
from aobake.io.plyparse import PlyList, read_ply, read_ply_header

# plyfile's (text, byte_order) for each encoding
ENCODINGS = {
    "ascii": (True, "="),
    "binary_little_endian": (False, "<"),
    "binary_big_endian": (False, ">"),
}

SCALARS = ["i1", "u1", "i2", "u2", "i4", "u4", "f4", "f8"]

# rows of mixed polygon sizes, and the values the parser must return for them
POLYGONS = [[0, 1, 2, 3], [1, 4, 2], [1, 4, 5, 2, 0], [3, 2, 5]]


def _write(path, elements, encoding, comments=()):
    text, byte_order = ENCODINGS[encoding]
    PlyData(elements, text=text, byte_order=byte_order, comments=list(comments)).write(str(path))
    return path


def _scalar_vertices(n=5):
    """Every PLY scalar type, with values at the ends of each type's range."""
    rng = np.random.default_rng(7)
    vertex = np.zeros(n, dtype=[(f"p_{code}", code) for code in SCALARS])
    for code in SCALARS:
        if code[0] == "f":
            vertex[f"p_{code}"] = rng.normal(size=n) * 1e3
        else:
            info = np.iinfo(code)
            vertex[f"p_{code}"] = [info.min, info.max, 0, 1, info.max // 3][:n]
    return vertex


def _polygon_faces(polygons=POLYGONS, len_type="u1", val_type="i4"):
    # no scalar beside the list: plyfile 1.x writes those in native byte order even in
    # big-endian files (test_scalars_after_varying_lists spells such rows out by hand)
    face = np.empty(len(polygons), dtype=[("vertex_indices", "O")])
    face["vertex_indices"] = [np.array(p, dtype=val_type) for p in polygons]
    return PlyElement.describe(
        face, "face", len_types={"vertex_indices": len_type}, val_types={"vertex_indices": val_type}
    )


def _fail_message(path, **kwargs):
    with pytest.raises(InputError) as info:
        read_ply(path, **kwargs)
    message = str(info.value)
    assert "\n" not in message and "\r" not in message
    assert message.startswith(f"{path.name}: cannot read as PLY: "), message
    return message


# -- the three encodings -------------------------------------------------------------


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
def test_scalar_types_in_every_encoding(tmp_path, encoding):
    vertex = _scalar_vertices()
    path = _write(tmp_path / "s.ply", [PlyElement.describe(vertex, "vertex")], encoding)
    ply = read_ply(path)
    assert ply.header.format == encoding
    assert ply.header.elements == {"vertex": (5, tuple(f"p_{c}" for c in SCALARS))}
    columns = ply.elements["vertex"].properties
    for code in SCALARS:
        got = columns[f"p_{code}"]
        if code[0] == "f" and encoding == "ascii":
            # ASCII floats keep the text's precision; plyfile prints float32 with repr
            assert got.dtype == np.float64
            np.testing.assert_array_equal(got.astype(code), vertex[f"p_{code}"])
        else:
            assert got.dtype == np.dtype(code)  # native byte order, declared type
            np.testing.assert_array_equal(got, vertex[f"p_{code}"])


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
def test_mixed_polygon_sizes(tmp_path, encoding):
    vertex = np.zeros(6, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    vertex["x"] = np.arange(6)
    elements = [PlyElement.describe(vertex, "vertex"), _polygon_faces()]
    ply = read_ply(_write(tmp_path / "p.ply", elements, encoding))
    counts, values = ply.elements["face"].properties["vertex_indices"]
    assert counts.dtype == np.int64 and values.dtype == np.int32
    np.testing.assert_array_equal(counts, [4, 3, 5, 3])
    np.testing.assert_array_equal(values, np.concatenate(POLYGONS))
    np.testing.assert_array_equal(ply.elements["vertex"].properties["x"], np.arange(6))


@pytest.mark.parametrize("order", ["<", ">"])
def test_scalars_after_varying_lists(tmp_path, order):
    rows = [([0, 1, 2, 3], -2, 0.5), ([1, 4, 2], 300, -1.25), ([5, 6, 7, 8, 9], 7, 2.0)]
    body = b""
    for indices, flag, weight in rows:
        body += bytes([len(indices)]) + np.array(indices, order + "i4").tobytes()
        body += np.array(flag, order + "i2").tobytes() + np.array(weight, order + "f8").tobytes()
    fmt = {"<": b"binary_little_endian", ">": b"binary_big_endian"}[order]
    path = tmp_path / "s.ply"
    path.write_bytes(
        b"ply\nformat " + fmt + b" 1.0\nelement face 3\nproperty list uchar int vertex_indices\n"
        b"property short flag\nproperty double weight\nend_header\n" + body
    )
    face = read_ply(path).elements["face"].properties
    np.testing.assert_array_equal(face["vertex_indices"].counts, [4, 3, 5])
    np.testing.assert_array_equal(
        face["vertex_indices"].values, [0, 1, 2, 3, 1, 4, 2, 5, 6, 7, 8, 9]
    )
    np.testing.assert_array_equal(face["flag"], [-2, 300, 7])
    np.testing.assert_array_equal(face["weight"], [0.5, -1.25, 2.0])
    assert face["flag"].dtype == np.int16 and face["weight"].dtype == np.float64


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
def test_uniform_lists_take_the_fast_path_and_read_the_same(tmp_path, encoding):
    triangles = [[0, 1, 2], [2, 1, 0], [1, 1, 1]]
    ply = read_ply(_write(tmp_path / "t.ply", [_polygon_faces(triangles)], encoding))
    counts, values = ply.elements["face"].properties["vertex_indices"]
    np.testing.assert_array_equal(counts, [3, 3, 3])
    np.testing.assert_array_equal(values, np.concatenate(triangles))


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
@pytest.mark.parametrize("len_type", ["u1", "i1", "u2", "i2", "u4", "i4"])
@pytest.mark.parametrize("val_type", ["u1", "i2", "u4", "i4", "f4", "f8"])
def test_list_property_types(tmp_path, encoding, len_type, val_type):
    polygons = [[0, 1, 2], [], [3, 4, 5, 6, 7], [8]]
    path = _write(tmp_path / "l.ply", [_polygon_faces(polygons, len_type, val_type)], encoding)
    column = read_ply(path).elements["face"].properties["vertex_indices"]
    assert isinstance(column, PlyList)
    np.testing.assert_array_equal(column.counts, [3, 0, 5, 1])
    np.testing.assert_array_equal(column.values, np.arange(9))
    expected = np.float64 if (val_type[0] == "f" and encoding == "ascii") else np.dtype(val_type)
    assert column.values.dtype == expected


@pytest.mark.filterwarnings("ignore:loadtxt")  # plyfile reading an empty ASCII list
@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
def test_random_polygon_lists_match_plyfile(tmp_path, encoding):
    rng = np.random.default_rng(3)
    polygons = [list(rng.integers(0, 1000, size=rng.integers(0, 9))) for _ in range(300)]
    path = _write(tmp_path / "r.ply", [_polygon_faces(polygons)], encoding)
    counts, values = read_ply(path).elements["face"].properties["vertex_indices"]
    theirs = PlyData.read(str(path))["face"].data["vertex_indices"]
    np.testing.assert_array_equal(counts, [len(p) for p in theirs])
    np.testing.assert_array_equal(values, np.concatenate(list(theirs)))


def test_empty_elements_and_element_without_properties(tmp_path):
    path = tmp_path / "e.ply"
    path.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\n"
        b"element face 0\nproperty list uchar int vertex_indices\nelement marker 3\n"
        b"end_header\n"
    )
    ply = read_ply(path)
    assert ply.elements["vertex"].properties["x"].shape == (0,)
    counts, values = ply.elements["face"].properties["vertex_indices"]
    assert counts.shape == (0,) and values.shape == (0,) and values.dtype == np.int32
    assert ply.elements["marker"].count == 3 and ply.elements["marker"].properties == {}


# -- header details ------------------------------------------------------------------


def test_comments_obj_info_crlf_and_latin1(tmp_path):
    path = tmp_path / "c.ply"
    path.write_bytes(
        b"ply\r\nformat ascii 1.0\r\ncomment made by caf\xe9\r\nobj_info not a comment\r\n"
        b"comment second\r\nelement vertex 2\r\nproperty float x\r\nend_header\r\n1.5\r\n-2\r\n"
    )
    header = read_ply_header(path)
    assert header.comments == ("made by caf\xe9", "second")
    np.testing.assert_array_equal(read_ply(path).elements["vertex"].properties["x"], [1.5, -2.0])


def test_comments_written_by_plyfile(tmp_path):
    vertex = np.zeros(1, dtype=[("x", "f4")])
    path = _write(
        tmp_path / "c.ply",
        [PlyElement.describe(vertex, "vertex")],
        "binary_big_endian",
        ["a", "b c"],
    )
    assert read_ply_header(path).comments == ("a", "b c")


def test_ascii_rows_may_wrap_over_lines(tmp_path):
    path = tmp_path / "w.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 1\n2\n3\n3 0\n1 1\n"
    )
    ply = read_ply(path)
    np.testing.assert_array_equal(ply.elements["vertex"].properties["y"], [1.0, 3.0])
    np.testing.assert_array_equal(
        ply.elements["face"].properties["vertex_indices"].values, [0, 1, 1]
    )


def test_list_length_written_as_a_whole_float(tmp_path):
    path = tmp_path / "f.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement face 2\nproperty list uchar int vertex_indices\n"
        "end_header\n3.0 0 1 2\n4 0 1 2 3\n"
    )
    counts, values = read_ply(path).elements["face"].properties["vertex_indices"]
    np.testing.assert_array_equal(counts, [3, 4])
    np.testing.assert_array_equal(values, [0, 1, 2, 0, 1, 2, 3])


def test_reading_some_elements_stops_after_the_last_wanted(tmp_path):
    # the face element is cut short: only a full read notices
    path = tmp_path / "s.ply"
    head = (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float ao\n"
        b"element face 5\nproperty list uchar int vertex_indices\nend_header\n"
    )
    path.write_bytes(head + np.array([0.25, 0.5], "<f4").tobytes() + b"\x03\x00")
    ply = read_ply(path, elements=("vertex",))
    assert list(ply.elements) == ["vertex"]
    np.testing.assert_array_equal(ply.elements["vertex"].properties["ao"], [0.25, 0.5])
    assert "file ends before its 5 face elements (truncated)" in _fail_message(path)


# -- truncated bodies ----------------------------------------------------------------


def _mesh_elements():
    vertex = np.zeros(4, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    vertex["x"] = [0, 1, 2, 3]
    return [
        PlyElement.describe(vertex, "vertex"),
        _polygon_faces([[0, 1, 2], [0, 2, 3, 1], [3, 2, 1]]),
    ]


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
@pytest.mark.parametrize("where, element", [("vertices", "4 vertex"), ("faces", "3 face")])
def test_truncated_body(tmp_path, encoding, where, element):
    whole = _write(tmp_path / "whole.ply", _mesh_elements(), encoding).read_bytes()
    cut = whole.index(b"end_header\n") + len(b"end_header\n")
    head, body = whole[:cut], whole[cut:]
    if encoding == "ascii":  # cut by numbers, not bytes
        tokens = body.split()
        body = b" ".join(tokens[:5] if where == "vertices" else tokens[:-1]) + b"\n"
    else:  # 5 bytes into the first vertex, or 3 bytes short of the last (varying) polygon
        body = body[:5] if where == "vertices" else body[:-3]
    path = tmp_path / "cut.ply"
    path.write_bytes(head + body)
    assert f"file ends before its {element} elements (truncated)" in _fail_message(path)


def test_truncated_uniform_binary_lists(tmp_path):
    path = _write(tmp_path / "t.ply", [_polygon_faces([[0, 1, 2]] * 4)], "binary_little_endian")
    path.write_bytes(path.read_bytes()[:-4])
    assert "file ends before its 4 face elements (truncated)" in _fail_message(path)


def test_empty_file_and_header_only(tmp_path):
    empty = tmp_path / "empty.ply"
    empty.write_bytes(b"")
    assert "not a PLY file (no 'ply' magic)" in _fail_message(empty)
    head = tmp_path / "head.ply"
    head.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty double x\nend_header\n"
    )
    assert "file ends before its 1 vertex elements (truncated)" in _fail_message(head)


# -- bad headers and bad bodies ------------------------------------------------------

HEAD = b"ply\nformat ascii 1.0\n"


def _line(text, reason):
    return f"bad PLY header line {text!r} ({reason})"


@pytest.mark.parametrize(
    "data, problem",
    [
        (b"\x00\x01binary" * 10, "not a PLY file (no 'ply' magic)"),
        (b"plyx\nformat ascii 1.0\nend_header\n", "not a PLY file (no 'ply' magic)"),
        (HEAD + b"element vertex 1\nproperty float x\n0\n", "not a PLY file (no 'end_header' line)"),
        (b"ply\nelement vertex 0\nend_header\n", "header has no 'format' line"),
        (b"ply\nformat binary_middle_endian 1.0\nend_header\n",
         _line("format binary_middle_endian 1.0", "unsupported format 'binary_middle_endian'")),
        (HEAD + b"elemnt vertex 1\nend_header\n", _line("elemnt vertex 1", "unknown keyword 'elemnt'")),
        (HEAD + b"element vertex 1\nproperty flot x\nend_header\n",
         _line("property flot x", "unknown type 'flot'")),
        (HEAD + b"property float x\nend_header\n", _line("property float x", "property before any element")),
        (HEAD + b"element v 0\nelement v 0\nend_header\n", _line("element v 0", "element 'v' declared twice")),
        (HEAD + b"element v 0\nproperty float x\nproperty int x\nend_header\n",
         _line("property int x", "property 'x' declared twice")),
        (HEAD + b"element v -1\nend_header\n", _line("element v -1", "negative count -1")),
        (HEAD + b"element v 0\nproperty list float int i\nend_header\n",
         _line("property list float int i", "list count type 'float' is not an integer type")),
        (HEAD + b"element v 0\nproperty list uchar int\nend_header\n",
         _line("property list uchar int", "too few words")),
        (HEAD + b"element v\nend_header\n", _line("element v", "too few words")),
    ],
)  # fmt: skip
def test_bad_header(tmp_path, data, problem):
    path = tmp_path / "bad.ply"
    path.write_bytes(data)
    assert _fail_message(path) == f"bad.ply: cannot read as PLY: {problem}"


@pytest.mark.parametrize(
    "body, problem",
    [
        (b"0 0 0\nabc 1 0\n3 0 1 2\n", "bad ASCII data in element 'vertex': 'abc' is not a number"),
        (b"0 0 0\n1 1 0\n2.5 0 1 2\n", "bad ASCII data in element 'face': list length '2.5' is not an integer"),
        (b"0 0 0\n1 1 0\nx 0 1 2\n", "bad ASCII data in element 'face': 'x' is not a number"),
        (b"0 0 0\n1 1 0\n-1 0\n", "negative list length in element 'face'"),
        (b"0 0 300\n1 1 0\n3 0 1 1\n", "property 'c' (uint8) holds 300"),
        (b"0 0 0.5\n1 1 0\n3 0 1 1\n", "property 'c' (uint8) holds 0.5"),
        (b"0 0 0\n1 1 0\n3 0 1.5 1\n", "property 'i' (int32) holds 1.5"),
    ],
)  # fmt: skip
def test_bad_ascii_body(tmp_path, body, problem):
    path = tmp_path / "bad.ply"
    path.write_bytes(
        HEAD + b"element vertex 2\nproperty float x\nproperty float y\nproperty uchar c\n"
        b"element face 1\nproperty list char int i\nend_header\n" + body
    )
    assert problem in _fail_message(path)


def test_negative_binary_list_length(tmp_path):
    path = tmp_path / "neg.ply"
    path.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement face 2\nproperty list char int i\n"
        b"end_header\n\x01" + np.int32(4).tobytes() + b"\xff"
    )
    assert "negative list length in element 'face'" in _fail_message(path)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(InputError, match=r"^nothing\.ply: file not found$"):
        read_ply(tmp_path / "nothing.ply")
    (tmp_path / "dir.ply").mkdir()
    with pytest.raises(InputError, match=r"^dir\.ply: is a directory, not a PLY file$"):
        read_ply(tmp_path / "dir.ply")


def test_bytes_given_are_parsed_instead_of_the_file(tmp_path):
    data = HEAD + b"element vertex 1\nproperty int k\nend_header\n42\n"
    ply = read_ply(tmp_path / "never_written.ply", data)
    np.testing.assert_array_equal(ply.elements["vertex"].properties["k"], [42])
