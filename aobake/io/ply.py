"""PLY: meshes in (any PLY: ASCII or binary, polygons of mixed sizes), bakes out (a
per-vertex float32 ``ao``), and ``ao`` read back from any tool's PLY.

Computes no AO; no trimesh. Parsing is :mod:`aobake.io.plyparse`. Writing is ours, not
trimesh's exporter: that needs a ``Trimesh`` and writes whatever dtype an attribute has
(a float64 ``ao`` becomes ``double``); here ``ao`` is always ``float`` by construction.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..errors import InputError, OutputError
from ..mesh import RawPart, fan_triangulate
from .color import CHANNELS, quantize, srgb_bytes
from .common import atomic_write, check_ao, check_attributes, check_display, output_name
from .plyparse import PlyData, PlyList, read_bytes, read_ply, read_ply_header, read_ply_types

#: Largest index a PLY ``int`` (int32) face index can hold.
INT32_MAX = int(np.iinfo(np.int32).max)


#: numpy type code -> PLY type name, for writing properties back with their types.
PLY_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
             "u4": "uint", "f4": "float", "f8": "double"}  # fmt: skip

#: Vertex colour properties, in channel order (R G B A).
COLOR_NAMES = ("red", "green", "blue", "alpha")

#: Suffixes of the PLY properties of a three-component extra attribute, by kind.
_COMPONENT_SUFFIXES = {"normal": ("_x", "_y", "_z"), "color": ("_r", "_g", "_b")}


def property_names(name: str, kind: str) -> tuple[str, ...]:
    """The PLY vertex properties an extra attribute is written as: ``bentNormal_x ...``
    for a normal, ``irradiance_r ...`` for a colour, ``name`` for a float."""
    return tuple(name + suffix for suffix in _COMPONENT_SUFFIXES.get(kind, ("",)))


def read_parts(path: Path, data: bytes, metadata: dict | None = None) -> list[RawPart]:
    """Vertices (``x y z``, optional ``nx ny nz``) and polygon faces of a PLY.

    Faces may mix polygon sizes; they keep their polygons (fan-triangulated for tracing).
    Other elements and properties (colours, edges...) are not used for the bake; they go
    into ``metadata["ply"]`` (a :class:`KeptPly`) so that a PLY output keeps them, and
    the comments ``aobake up_axis=Y|Z`` and ``aobake meters_per_unit=M`` an aobake PLY
    records go into ``metadata["up_axis"]`` and ``metadata["meters_per_unit"]``.
    """
    ply = read_ply(path, data)
    if metadata is not None:
        metadata["ply"] = KeptPly(ply, read_ply_types(path, data))
        metadata.update(_recorded_metrics(ply.header.comments))
    vertex = ply.elements.get("vertex")
    if vertex is None:
        return []
    columns = vertex.properties
    missing = [axis for axis in "xyz" if not isinstance(columns.get(axis), np.ndarray)]
    if missing:
        raise InputError(path, f"cannot read as PLY: vertex element lacks property {missing[0]!r}")
    positions = np.column_stack([columns[axis] for axis in "xyz"]).astype(np.float64)
    if metadata is not None:
        for k, axis in enumerate("xyz"):  # kept as views of these exact values (no copy)
            kind, size = columns[axis].dtype.kind, columns[axis].dtype.itemsize
            if kind == "f" or (kind in "iu" and size <= 4):
                columns[axis] = positions[:, k]
    normals = None
    if all(isinstance(columns.get(key), np.ndarray) for key in ("nx", "ny", "nz")):
        normals = np.column_stack([columns[key] for key in ("nx", "ny", "nz")]).astype(np.float64)
    counts, corners = np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    face = ply.elements.get("face")
    lists = {} if face is None else face.properties
    lists = {key: value for key, value in lists.items() if isinstance(value, PlyList)}
    if lists:
        key = next((k for k in ("vertex_indices", "vertex_index") if k in lists), next(iter(lists)))
        counts, corners = lists[key]
        if corners.dtype.kind == "f" and not (corners == np.round(corners)).all():
            raise InputError(path, f"cannot read as PLY: face {key!r} holds non-integer indices")
        integral = corners.dtype.kind in "iu"
        corners = corners.astype(np.int64)
        if counts.size and corners.size == 3 * counts.size and (counts == 3).all():
            counts = np.broadcast_to(np.int64(3), counts.shape)  # read-only, no memory
        if integral and metadata is not None:
            # the kept list shares these exact values (writers cast to the declared type)
            face.properties[key] = PlyList(counts, corners)
    if counts.size and corners.size == 3 * counts.size and (counts == 3).all():
        faces = corners.reshape(-1, 3)  # all triangles: the polygons' own array, no copy
    else:
        faces = fan_triangulate(counts, corners)
    return [RawPart(path.stem, positions, faces, normals, counts, corners)]


def write_ply(
    path: str | Path,
    positions,
    faces,
    ao,
    *,
    normals=None,
    color: bool = False,
    comments: Iterable[str] = (),
    attributes=None,
    display=None,
) -> None:
    """Write a binary little-endian PLY with a float32 per-vertex ``ao`` property.

    Vertex properties, in order: ``x y z`` (float), ``nx ny nz`` (float, when
    ``normals`` is given), ``ao`` (float), ``quality`` (float, the same value: MeshLab's
    per-vertex quality slot), and ``red green blue`` (uchar, grey ``round(255 * ao)``)
    when ``color`` is true (sRGB-encoded, :func:`aobake.io.color.srgb_bytes`: Blender and
    MeshLab decode PLY colours as sRGB and then show the grey USD's linear
    ``displayColor`` shows). Faces are ``list uchar int vertex_indices``. Vertices are
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
    attributes : mapping of str to array, optional
        Extra per-vertex values (:func:`aobake.io.common.check_attributes`), float32
        properties after ``quality``: ``name_x name_y name_z`` for normals, ``name_r
        name_g name_b`` for colours, ``name`` for floats.
    display : (n, 3) float in [0, 1], optional
        Linear colours that ``color`` writes (sRGB bytes) instead of grey ``ao``.

    Raises
    ------
    NumericalError
        ``ao``, ``attributes`` or ``display`` is non-finite, out of range, or not one
        value per vertex (checked before anything is opened).
    InputError
        A face references a vertex outside ``[0, n)``.
    OutputError
        The directory is missing or unwritable, the mesh has more vertices than int32
        indices can address, or a coordinate overflows float32.
    ValueError
        Arrays of the wrong shape, or a comment containing a newline.
    """
    path = Path(path)
    positions = np.asarray(positions)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise ValueError(f"positions must have shape (n, 3), got {positions.shape}")
    n = positions.shape[0]
    ao32 = check_ao(ao, n_vertices=n, where=output_name(path))
    extras = check_attributes(attributes, n, output_name(path))
    display32 = check_display(display, n, output_name(path))
    faces = np.asarray(faces)
    if faces.size == 0:
        faces = faces.reshape(0, 3)
    if faces.ndim != 2 or faces.shape[1] < 3 or faces.shape[1] > 255:
        raise ValueError(f"faces must have shape (m, k) with 3 <= k <= 255, got {faces.shape}")
    if not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"faces must be integers, got dtype {faces.dtype}")
    if n > INT32_MAX:
        raise OutputError(
            f"{output_name(path)}: {n} vertices exceed what PLY int32 face indices can address"
        )
    if faces.size:
        bad = (faces < 0) | (faces >= n)
        if bad.any():
            worst = int(faces[faces >= n].max()) if (faces >= n).any() else int(faces[bad].min())
            raise InputError(
                output_name(path),
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
    fields += [(column, "<f4") for name, (kind, _) in extras.items() for column in property_names(name, kind)]
    if color:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]

    # np.zeros, not np.empty: every field is assigned below, but a missed one must read 0.
    vertex = np.zeros(n, dtype=fields)
    with np.errstate(over="ignore"):
        pos32 = positions.astype(np.float32)
    if not np.isfinite(pos32).all():
        raise OutputError(
            f"{output_name(path)}: coordinates are non-finite or overflow float32; cannot write PLY"
        )
    vertex["x"], vertex["y"], vertex["z"] = pos32.T
    if normals is not None:
        n32 = normals.astype(np.float32)
        vertex["nx"], vertex["ny"], vertex["nz"] = n32.T
    vertex["ao"] = ao32
    vertex["quality"] = ao32
    for name, (kind, values) in extras.items():
        for k, column in enumerate(property_names(name, kind)):
            vertex[column] = values if values.ndim == 1 else values[:, k]
    if color and display32 is not None:
        for k, column in enumerate(COLOR_NAMES[:3]):
            vertex[column] = srgb_bytes(display32[:, k])
    elif color:
        vertex["red"] = vertex["green"] = vertex["blue"] = srgb_bytes(ao32)

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
    _write(path, header, [vertex.data, face.data])


def _write(path: Path, header: list[str], chunks) -> None:
    """Header lines and body chunks, atomically."""
    head = ("\n".join(header) + "\n").encode("ascii", errors="backslashreplace")
    try:
        with atomic_write(path) as tmp, open(tmp, "wb") as fh:
            fh.write(head)
            for chunk in chunks:
                fh.write(chunk)
    except OSError as exc:
        raise OutputError(f"{output_name(path)}: cannot write ({exc.strerror or exc})") from exc


def read_ao_ply(path: str | Path) -> np.ndarray:
    """Read the per-vertex ``ao`` property of a PLY file (``quality`` if there is no ``ao``).

    Reads ASCII, binary little-endian and binary big-endian PLY, from aobake or any
    other tool (parsed by :func:`aobake.io.plyparse.read_ply`). Only the header, the vertex
    element and the elements before it are parsed.

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
    data = read_bytes(path)
    # check the header first: a file without the property fails on that, not on its body
    vertex = read_ply_header(path, data).elements.get("vertex")
    if vertex is None:
        raise InputError(path, "PLY has no vertex element")
    names = vertex[1]
    key = next((k for k in ("ao", "quality") if k in names), None)
    if key is None:
        raise InputError(
            path, f"PLY vertices have no 'ao' or 'quality' property (found: {', '.join(names)})"
        )
    column = read_ply(path, data, elements=("vertex",)).elements["vertex"].properties[key]
    if isinstance(column, PlyList):
        raise InputError(path, f"PLY vertex property {key!r} is a list, not one value per vertex")
    return np.ascontiguousarray(column, dtype=np.float64)


# -- a PLY input written back whole ------------------------------------------------------


class KeptPly(NamedTuple):
    """A PLY input as read, for writing it back with ``ao`` added.

    Attributes
    ----------
    data : PlyData
        Every element and property; the vertices' ``x y z`` as float64 views of the
        surface's positions and the faces' integer index list as int64 (the corners
        the surface's polygons share): the same values as the declared types, which
        the writers cast back to.
    types : dict of str to tuple of (name, dtype, count dtype or None)
        The declared types (:func:`aobake.io.plyparse.read_ply_types`).
    """

    data: PlyData
    types: dict


def _recorded_metrics(comments) -> dict:
    """``up_axis`` and ``meters_per_unit`` from ``aobake key=value`` comments, when valid."""
    out: dict = {}
    for comment in comments:
        key, _, value = comment.removeprefix("aobake ").partition("=")
        if not comment.startswith("aobake "):
            continue
        if key == "up_axis" and value.strip() in ("Y", "Z"):
            out["up_axis"] = value.strip()
        elif key == "meters_per_unit":
            try:
                metres = float(value)
            except ValueError:
                continue
            if np.isfinite(metres) and metres > 0:
                out["meters_per_unit"] = metres
    return out


def vertex_colors(kept: KeptPly) -> tuple[np.ndarray, np.dtype] | None:
    """The input's vertex colours ``(n, 3 or 4)`` as stored and their dtype, or None."""
    columns = kept.data.elements["vertex"].properties
    names = [c for c in COLOR_NAMES if isinstance(columns.get(c), np.ndarray)]
    if names[:3] != list(COLOR_NAMES[:3]):
        return None
    dtype = dict((n, t) for n, t, _ in kept.types["vertex"])["red"]
    return np.column_stack([columns[c] for c in names]), dtype


def write_kept_ply(
    path: str | Path,
    kept: KeptPly,
    ao,
    *,
    color: bool = False,
    channel: str | None = None,
    comments: Iterable[str] = (),
    source: str = "input",
    attributes=None,
    display=None,
) -> None:
    """Write a PLY input back whole, with ``ao`` (and ``quality``) added to its vertices.

    Every element and property keeps its name, order and type (a ``double`` stays a
    ``double``); the body is binary little-endian. ``ao`` and ``quality`` are float32,
    replacing properties of those names in place or appended after the input's.
    ``color`` writes sRGB grey into ``red green blue`` (kept in their type, appended as
    uchar when absent; ``alpha`` untouched). ``channel`` (``"R"``, ``"G"``, ``"B"`` or
    ``"A"``) writes linear ``ao`` into one channel of the input's colours and keeps the
    others bit-identical (an absent ``alpha`` is added in the colours' type). The input's comments are kept except its own
    ``aobake ...`` lines, which ``comments`` replace. ``attributes`` are float32
    properties (see :func:`write_ply`), replacing the input's of the same names in
    place or appended; ``display`` is what ``color`` writes instead of grey.

    Raises
    ------
    NumericalError
        ``ao`` is non-finite, outside [0, 1] or not one value per vertex.
    InputError
        ``channel`` is given but the input has no ``red green blue`` colours.
    OutputError
        Unwritable directory.
    """
    path = Path(path)
    vertex = kept.data.elements["vertex"]
    ao32 = check_ao(ao, n_vertices=vertex.count, where=path.name)
    extras = check_attributes(attributes, vertex.count, path.name)
    display32 = check_display(display, vertex.count, path.name)
    types = {name: list(props) for name, props in kept.types.items()}
    columns = {name: dict(element.properties) for name, element in kept.data.elements.items()}
    props, vcols = types["vertex"], columns["vertex"]

    def put(name: str, values: np.ndarray, dtype) -> None:
        dtype = np.dtype(dtype)
        if not any(p[0] == name for p in props):
            props.append((name, dtype, None))
        else:
            dtype = next(t for n, t, _ in props if n == name)
        vcols[name] = quantize(values, dtype) if dtype.kind in "iu" else values.astype(dtype)

    def put_float(name: str, values: np.ndarray) -> None:  # replaced in place as float32, or appended
        props[:] = [(n, t, c) if n != name else (n, np.dtype(np.float32), None) for n, t, c in props]
        put(name, values, np.float32)

    for name in ("ao", "quality"):
        put_float(name, ao32)
    for name, (kind, values) in extras.items():
        for k, column in enumerate(property_names(name, kind)):
            put_float(column, values if values.ndim == 1 else values[:, k])
    if channel is not None:
        found = vertex_colors(kept)
        if found is None:
            raise InputError(source, f"--channel {channel}: the mesh has no vertex colours (red green blue)")
        put(COLOR_NAMES[CHANNELS[channel]], ao32.astype(np.float64), found[1])
    elif color:
        shown = np.repeat(ao32[:, None], 3, axis=1) if display32 is None else display32
        for k, name in enumerate(COLOR_NAMES[:3]):
            put(name, srgb_bytes(shown[:, k]) / 255.0, np.uint8)  # 8-bit sRGB at any type's scale
    header = ["ply", "format binary_little_endian 1.0"]
    own = [c for c in kept.data.header.comments if not c.startswith("aobake ")]
    header += [f"comment {c}" if c else "comment" for c in own + [str(c) for c in comments]]
    chunks = []
    for name, element in kept.data.elements.items():
        header.append(f"element {name} {element.count}")
        for prop, dtype, counter in types[name]:
            if counter is None:
                header.append(f"property {PLY_NAMES[dtype.str[1:]]} {prop}")
            else:
                header.append(
                    f"property list {PLY_NAMES[counter.str[1:]]} {PLY_NAMES[dtype.str[1:]]} {prop}"
                )
        chunks.append(_element_bytes(element.count, types[name], columns[name]))
    header.append("end_header")
    _write(path, header, chunks)


def _element_bytes(count: int, props, columns: dict) -> bytes:
    """One element's rows as binary little-endian bytes, lists of any lengths."""
    little = [(np.dtype(t).newbyteorder("<"), None if c is None else np.dtype(c).newbyteorder("<"))
              for _, t, c in props]
    fixed = _fixed_rows(count, props, little, columns)
    if fixed is not None:
        return fixed
    return _scattered_rows(count, props, little, columns)


def _fixed_rows(count: int, props, little, columns: dict) -> bytes | None:
    """The rows as one packed structured array when every list has the same length in
    every row (triangle faces): the bytes of :func:`_scattered_rows` without its per-byte
    index arrays. None when some list varies in length."""
    fields, values = [], []
    for i, ((name, _, _), (dtype, counter)) in enumerate(zip(props, little, strict=True)):
        column = columns[name]
        if counter is None:
            fields.append((f"p{i}", dtype))
            values.append(np.asarray(column).astype(dtype))
            continue
        counts, items = column
        length = int(counts[0]) if count else 0
        if count and not (counts == length).all():
            return None
        fields.append((f"n{i}", counter))
        values.append(counts.astype(counter))
        if length:
            fields.append((f"p{i}", dtype, (length,)))
            values.append(np.asarray(items).astype(dtype).reshape(count, length))
    rows = np.empty(count, dtype=np.dtype(fields))
    for (key, *_), value in zip(fields, values, strict=True):
        rows[key] = value
    return rows.tobytes()


def _scattered_rows(count: int, props, little, columns: dict) -> bytes:
    """The rows byte by byte: each property scattered to its offset in each row."""
    row = np.zeros(count, dtype=np.int64)  # bytes per row
    for (name, _, _), (dtype, counter) in zip(props, little, strict=True):
        if counter is None:
            row += dtype.itemsize
        else:
            row += counter.itemsize + columns[name].counts * dtype.itemsize
    starts = np.cumsum(row) - row
    out = np.zeros(int(row.sum()), dtype=np.uint8)
    at = starts.copy()  # where the next property of each row goes

    def scatter(where: np.ndarray, values: np.ndarray) -> None:
        if not len(where):  # no rows, or every list empty
            return
        raw = np.ascontiguousarray(values).view(np.uint8).reshape(len(where), -1)
        out[where[:, None] + np.arange(raw.shape[1])] = raw

    for (name, _, _), (dtype, counter) in zip(props, little, strict=True):
        column = columns[name]
        if counter is None:
            scatter(at, np.asarray(column).astype(dtype))
            at = at + dtype.itemsize
            continue
        counts, values = column
        scatter(at, counts.astype(counter))
        at = at + counter.itemsize
        owner = np.repeat(np.arange(count), counts)
        k = np.arange(len(values)) - np.repeat(np.cumsum(counts) - counts, counts)
        scatter(at[owner] + k * dtype.itemsize, np.asarray(values).astype(dtype))
        at = at + counts * dtype.itemsize
    return out.tobytes()


def read_colours_ply(path: str | Path) -> np.ndarray:
    """(n, 3) linear RGB of a PLY's vertex ``red green blue``: integers normalised and,
    as viewers do (:mod:`aobake.io.color`), decoded from sRGB; floats taken as sRGB in [0, 1]."""
    from .color import srgb_to_linear

    path = Path(path)
    data = read_bytes(path)
    vertex = read_ply_header(path, data).elements.get("vertex")
    names = () if vertex is None else vertex[1]
    if not all(k in names for k in ("red", "green", "blue")):
        raise InputError(path, "PLY vertices have no colours (red, green, blue) to show")
    props = read_ply(path, data, elements=("vertex",)).elements["vertex"].properties
    channels = []
    for key in ("red", "green", "blue"):
        column = props[key]
        if isinstance(column, PlyList):
            raise InputError(path, f"PLY vertex property {key!r} is a list, not one value per vertex")
        column = np.asarray(column)
        top = float(np.iinfo(column.dtype).max) if column.dtype.kind in "iu" else 1.0
        channels.append(column.astype(np.float64) / top)
    return srgb_to_linear(np.stack(channels, axis=1))
