"""PLY output with a per-vertex ``ao`` property, and reading ``ao`` back from any PLY.

Arrays in, files out: computes no AO. Imports numpy and aobake's ``errors`` and
``io_common`` only (no trimesh, no plyfile).

Why not trimesh's exporter: the format is a short text header followed by two packed
numpy structured arrays, so writing it here is a few lines and every byte is ours.
trimesh's ``export_ply`` needs a ``Trimesh`` (whose constructor and caches we would have
to keep from touching the vertices), writes the dtype a custom attribute happens to have
(a float64 ``ao`` becomes ``double``), exports colour as RGBA and adds its own comment;
the layer rules also keep trimesh out of the writers (``mesh`` is its only importer).
Here the header is fixed by construction: ``ao`` is always ``float``. The reader is a
small parser of its own for the same reason; it handles ASCII and both binary
encodings, so PLY files from other tools (MeshLab, Blender, CloudCompare) read too.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from .errors import InputError, NumericalError, OutputError
from .io_common import atomic_write, check_ao

#: Largest index a PLY ``int`` (int32) face index can hold.
INT32_MAX = int(np.iinfo(np.int32).max)

#: A header longer than this is not a PLY header (guards against reading a huge binary).
_MAX_HEADER_BYTES = 1 << 20

#: PLY scalar type names (both spellings of the spec) and their numpy kinds.
_PLY_TYPES = {
    "char": "i1", "int8": "i1",
    "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4",
    "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4",
    "double": "f8", "float64": "f8",
}  # fmt: skip


def write_ply(
    path: str | Path,
    positions,
    faces,
    ao,
    *,
    normals=None,
    color: bool = False,
    comments: Iterable[str] = (),
) -> None:
    """Write a binary little-endian PLY with a float32 per-vertex ``ao`` property.

    Vertex properties, in order: ``x y z`` (float), ``nx ny nz`` (float, when
    ``normals`` is given), ``ao`` (float), ``quality`` (float, the same value: MeshLab's
    per-vertex quality slot), and ``red green blue`` (uchar, grey ``round(255 * ao)``)
    when ``color`` is true. Faces are ``list uchar int vertex_indices``. Vertices are
    written exactly as given (same count and order; duplicate and unreferenced
    vertices are kept).

    Parameters
    ----------
    path : str or Path
        Output file; written atomically (temporary file in the same directory, then
        rename), so on any failure neither it nor a temporary file is left behind.
    positions : (n, 3) float
        Vertex positions. PLY ``float`` is float32, so float64 positions are rounded to
        float32 on writing (about 7 significant digits; recentre beforehand if the mesh
        sits far from the origin and that matters).
    faces : (m, k) int
        Polygons as vertex indices, k >= 3 corners each (triangles: k = 3).
    ao : (n,) float in [0, 1]
        Accessibility 1 - A (1 = fully open), stored as float32.
    normals : (n, 3) float, optional
        Vertex normals, stored as float32 ``nx ny nz``.
    color : bool
        Also write ``ao`` as grey ``red green blue`` so viewers show it without setup.
    comments : iterable of str
        Header comment lines (no newlines), written in order after the format line.

    Raises
    ------
    NumericalError
        ``ao`` is non-finite, outside [0, 1], or not one value per vertex (checked
        before anything is opened).
    InputError
        A face references a vertex outside ``[0, n)``.
    OutputError
        The directory is missing or unwritable, the mesh has more vertices than int32
        indices can address, or a coordinate overflows float32.
    ValueError
        Arrays of the wrong shape, or a comment containing a newline.
    """
    path = Path(path)
    ao32 = check_ao(ao)
    positions = np.asarray(positions)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise ValueError(f"positions must have shape (n, 3), got {positions.shape}")
    n = positions.shape[0]
    if ao32.shape != (n,):
        raise NumericalError(
            f"{path.name}: ao has shape {ao32.shape} but the mesh has {n} vertices"
        )
    faces = np.asarray(faces)
    if faces.size == 0:
        faces = faces.reshape(0, 3)
    if faces.ndim != 2 or faces.shape[1] < 3 or faces.shape[1] > 255:
        raise ValueError(f"faces must have shape (m, k) with 3 <= k <= 255, got {faces.shape}")
    if not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"faces must be integers, got dtype {faces.dtype}")
    if n > INT32_MAX:
        raise OutputError(
            f"{path.name}: {n} vertices exceed what PLY int32 face indices can address"
        )
    if faces.size:
        bad = (faces < 0) | (faces >= n)
        if bad.any():
            worst = int(faces[faces >= n].max()) if (faces >= n).any() else int(faces[bad].min())
            raise InputError(
                path,
                f"{int(bad.any(axis=1).sum())} faces reference vertex {worst} "
                f"but the mesh has {n} vertices",
            )
    comment_lines = [str(c) for c in comments]
    for c in comment_lines:
        if "\n" in c or "\r" in c:
            raise ValueError(f"PLY comments cannot contain newlines: {c!r}")

    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if normals is not None:
        normals = np.asarray(normals)
        if normals.shape != (n, 3):
            raise ValueError(f"normals have shape {normals.shape}, positions {positions.shape}")
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    fields += [("ao", "<f4"), ("quality", "<f4")]
    if color:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]

    # np.zeros, not np.empty: every field is assigned below, but a missed one must read 0.
    vertex = np.zeros(n, dtype=fields)
    with np.errstate(over="ignore"):
        pos32 = positions.astype(np.float32)
    if not np.isfinite(pos32).all():
        raise OutputError(
            f"{path.name}: coordinates are non-finite or overflow float32; cannot write PLY"
        )
    vertex["x"], vertex["y"], vertex["z"] = pos32.T
    if normals is not None:
        n32 = normals.astype(np.float32)
        vertex["nx"], vertex["ny"], vertex["nz"] = n32.T
    vertex["ao"] = ao32
    vertex["quality"] = ao32
    if color:
        grey = np.rint(ao32.astype(np.float64) * 255.0).astype(np.uint8)
        vertex["red"] = vertex["green"] = vertex["blue"] = grey

    k = faces.shape[1]
    face = np.zeros(faces.shape[0], dtype=[("count", "u1"), ("vertex_indices", "<i4", (k,))])
    face["count"] = k
    face["vertex_indices"] = faces.astype(np.int32)

    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {c}" if c else "comment" for c in comment_lines]
    header.append(f"element vertex {n}")
    for name, kind in fields:
        header.append(f"property {'float' if kind == '<f4' else 'uchar'} {name}")
    header += [
        f"element face {faces.shape[0]}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    head = ("\n".join(header) + "\n").encode("ascii", errors="backslashreplace")

    try:
        with atomic_write(path) as tmp, open(tmp, "wb") as fh:
            fh.write(head)
            fh.write(vertex.data)
            fh.write(face.data)
    except OSError as exc:
        raise OutputError(f"{path.name}: cannot write ({exc.strerror or exc})") from exc


def read_ao_ply(path: str | Path) -> np.ndarray:
    """Read the per-vertex ``ao`` property of a PLY file (``quality`` if there is no ``ao``).

    Reads ASCII, binary little-endian and binary big-endian PLY, from aobake or any
    other tool. Only the header and the vertex element are parsed.

    Parameters
    ----------
    path : str or Path
        A PLY file.

    Returns
    -------
    ao : (n,) float64
        One value per vertex, in file order. Values are returned as stored (a foreign
        ``quality`` property need not lie in [0, 1]).

    Raises
    ------
    InputError
        The file is missing, unreadable, not a PLY, truncated, or has no vertex
        ``ao``/``quality`` property; the one-line message starts with the file name.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(path, "file not found") from None
    except IsADirectoryError:
        raise InputError(path, "is a directory, not a PLY file") from None
    except OSError as exc:
        raise InputError(path, f"cannot read ({exc.strerror or exc})") from exc
    fmt, elements, body = _parse_header(path, data)
    names = [e[0] for e in elements]
    if "vertex" not in names:
        raise InputError(path, "PLY has no vertex element")
    vprops = elements[names.index("vertex")][2]
    pnames = [p[0] for p in vprops]
    if "ao" in pnames:
        key = "ao"
    elif "quality" in pnames:
        key = "quality"
    else:
        raise InputError(
            path, f"PLY vertices have no 'ao' or 'quality' property (found: {', '.join(pnames)})"
        )
    if fmt == "ascii":
        values = _read_ascii(path, data[body:], elements, key)
    else:
        values = _read_binary(
            path, data, body, elements, key, "<" if fmt == "binary_little_endian" else ">"
        )
    return np.ascontiguousarray(values, dtype=np.float64)


def _parse_header(path: Path, data: bytes):
    """Split a PLY header into (format, [(name, count, props)], body offset).

    ``props`` is a list of ``(name, kind)`` for scalars and ``(name, (count_kind,
    item_kind))`` for lists, kinds being numpy codes without byte order.
    """
    if not data.startswith(b"ply"):
        raise InputError(path, "not a PLY file (no 'ply' magic)")
    end = -1
    for marker in (b"end_header\n", b"end_header\r\n", b"end_header\r"):
        end = data.find(marker, 0, _MAX_HEADER_BYTES)
        if end >= 0:
            body = end + len(marker)
            break
    if end < 0:
        raise InputError(path, "not a PLY file (no 'end_header' line)")
    try:
        text = data[:end].decode("ascii")
    except UnicodeDecodeError:
        text = data[:end].decode("latin-1")
    fmt = None
    elements: list = []
    for raw in text.splitlines()[1:]:
        words = raw.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        try:
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                elements.append((words[1], int(words[2]), []))
            elif words[0] == "property":
                if not elements:
                    raise ValueError("property before any element")
                if words[1] == "list":
                    prop = (words[4], (_PLY_TYPES[words[2]], _PLY_TYPES[words[3]]))
                else:
                    prop = (words[2], _PLY_TYPES[words[1]])
                elements[-1][2].append(prop)
            else:
                raise ValueError(f"unknown keyword {words[0]!r}")
        except (IndexError, KeyError, ValueError) as exc:
            raise InputError(path, f"bad PLY header line {raw.strip()!r} ({exc})") from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise InputError(path, f"unsupported PLY format {fmt!r}")
    for name, count, _ in elements:
        if count < 0:
            raise InputError(path, f"PLY element {name!r} has a negative count {count}")
    return fmt, elements, body


def _read_ascii(path: Path, body: bytes, elements, key: str) -> np.ndarray:
    """Values of vertex property ``key`` from an ASCII PLY body (one row per line)."""
    lines = [line for line in body.decode("latin-1").splitlines() if line.strip()]
    row = 0
    for name, count, props in elements:
        if name != "vertex":
            row += count  # one line per row, whatever its lists hold
            continue
        rows = lines[row : row + count]
        if len(rows) < count:
            raise InputError(
                path, f"truncated: {count} vertices declared, {len(rows)} rows present"
            )
        try:
            if all(not isinstance(kind, tuple) for _, kind in props):
                table = np.array(" ".join(rows).split(), dtype=np.float64)
                if table.size != count * len(props):
                    raise ValueError(
                        f"{table.size} numbers for {count} rows of {len(props)} properties"
                    )
                return table.reshape(count, len(props))[:, [p[0] for p in props].index(key)]
            out = np.zeros(count)
            for i, line in enumerate(rows):
                out[i] = _ascii_row_value(line.split(), props, key)
            return out
        except ValueError as exc:
            raise InputError(path, f"bad ASCII vertex data ({exc})") from None
    raise AssertionError("unreachable: caller checked for a vertex element")


def _ascii_row_value(tokens: list[str], props, key: str) -> float:
    """The value of ``key`` in one ASCII row whose properties include lists."""
    pos = 0
    for name, kind in props:
        if isinstance(kind, tuple):
            pos += 1 + int(tokens[pos])
        else:
            if name == key:
                return float(tokens[pos])
            pos += 1
    raise ValueError("property not found in row")


def _read_binary(
    path: Path, data: bytes, offset: int, elements, key: str, order: str
) -> np.ndarray:
    """Values of vertex property ``key`` from a binary PLY body starting at ``offset``."""
    for name, count, props in elements:
        has_lists = any(isinstance(kind, tuple) for _, kind in props)
        if not has_lists:
            dtype = np.dtype([(p, order + kind) for p, kind in props])
            size = count * dtype.itemsize
            if offset + size > len(data):
                raise InputError(
                    path,
                    f"truncated: element {name!r} needs {size} bytes, {len(data) - offset} remain",
                )
            if name == "vertex":
                return np.frombuffer(data, dtype=dtype, count=count, offset=offset)[key]
            offset += size
        else:
            values, offset = _binary_rows_with_lists(path, data, offset, count, props, key, order)
            if name == "vertex":
                return values
    raise AssertionError("unreachable: caller checked for a vertex element")


def _binary_rows_with_lists(
    path: Path, data: bytes, offset: int, count: int, props, key: str, order: str
):
    """Walk ``count`` binary rows with list properties; return (values of ``key``, end offset).

    Row by row in Python: only foreign files put lists in the vertex element or an
    element before it, and those are small in practice.
    """
    out = np.zeros(count)
    try:
        for i in range(count):
            for name, kind in props:
                if isinstance(kind, tuple):
                    ctype = np.dtype(order + kind[0])
                    n_items = int(np.frombuffer(data, ctype, 1, offset)[0])
                    offset += ctype.itemsize + n_items * np.dtype(kind[1]).itemsize
                else:
                    dt = np.dtype(order + kind)
                    if name == key:
                        out[i] = np.frombuffer(data, dt, 1, offset)[0]
                    offset += dt.itemsize
    except ValueError:
        raise InputError(path, f"truncated binary data in row {i} of {count}") from None
    if offset > len(data):
        raise InputError(
            path, f"truncated binary data ({offset} bytes needed, {len(data)} present)"
        )
    return out, offset
