"""The one PLY parser: ASCII and binary (both byte orders), any elements and properties.

Imports numpy and aobake's ``errors`` only; :mod:`aobake.io.ply` reads meshes and ``ao``
through it. Not trimesh's reader: trimesh 5.2 misreads binary faces of mixed polygon
sizes and accepts truncated ASCII PLY as a smaller mesh.

Rows without list properties, and rows whose lists all keep the first row's length, are
read in one ``np.frombuffer`` with a structured dtype; only elements whose list lengths
vary are walked row by row, and then only to find the lengths. Every failure is an
:class:`~aobake.errors.InputError` with a one-line message starting
``"<file>: cannot read as PLY: "``.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..errors import InputError
from .common import check_input_file

#: PLY scalar type names (both spellings of the spec) and their numpy codes.
PLY_TYPES = {
    "char": "i1", "int8": "i1",
    "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4",
    "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4",
    "double": "f8", "float64": "f8",
}  # fmt: skip

#: The three encodings of the body, and the byte order of the binary ones.
PLY_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}

#: A header longer than this is not a PLY header (guards against scanning a huge binary).
_MAX_HEADER_BYTES = 1 << 20

#: The header's last line; the body starts after its line break (CR LF counts as one).
_END_HEADER = re.compile(rb"(?:\A|[\r\n])end_header[ \t]*(?:\r\n|\n|\r|\Z)")

_PREFIX = "cannot read as PLY: "


class PlyList(NamedTuple):
    """A list property of every row of an element, flattened.

    Attributes
    ----------
    counts : (rows,) int64
        Items in each row's list.
    values : (counts.sum(),) ndarray
        All rows' items in file order, of the declared item type (native byte order).
    """

    counts: np.ndarray
    values: np.ndarray


@dataclass(frozen=True)
class PlyElement:
    """One element (``vertex``, ``face``...) as read.

    Attributes
    ----------
    name : str
    count : int
        Number of rows.
    properties : dict of str to ndarray or PlyList
        In header order. Scalars are ``(count,)`` arrays of the declared type in native
        byte order, except that ASCII floating-point values keep the text's precision
        (float64); list properties are :class:`PlyList`.
    """

    name: str
    count: int
    properties: dict[str, np.ndarray | PlyList]


@dataclass(frozen=True)
class PlyHeader:
    """What a PLY header declares.

    Attributes
    ----------
    format : {"ascii", "binary_little_endian", "binary_big_endian"}
    elements : dict of str to (int, tuple of str)
        Every element in file order: its row count and its property names.
    comments : tuple of str
        ``comment`` lines, without the keyword.
    """

    format: str
    elements: dict[str, tuple[int, tuple[str, ...]]]
    comments: tuple[str, ...] = ()


@dataclass(frozen=True)
class PlyData:
    """A parsed PLY file.

    Attributes
    ----------
    header : PlyHeader
    elements : dict of str to PlyElement
        The elements read, in file order.
    """

    header: PlyHeader
    elements: dict[str, PlyElement]


@dataclass(frozen=True)
class _Property:
    """A header ``property`` line: value (or list item) type, and count type for lists."""

    name: str
    dtype: np.dtype
    count_dtype: np.dtype | None = None


@dataclass(frozen=True)
class _Element:
    """A header ``element`` line and its properties."""

    name: str
    count: int
    properties: tuple[_Property, ...]


def read_ply(
    path: str | Path, data: bytes | None = None, *, elements: Collection[str] | None = None
) -> PlyData:
    """Parse a PLY file: ASCII, binary little-endian or binary big-endian.

    Parameters
    ----------
    path : str or Path
        The file; read when ``data`` is None, and named in every error message.
    data : bytes, optional
        The file's contents, when the caller has read them already.
    elements : collection of str, optional
        Read only these elements. Elements before the last wanted one are still
        checked as far as is needed to find where it starts; elements after it are not
        looked at. Default: every element.

    Returns
    -------
    PlyData
        Per element, scalar properties as arrays and list properties as
        ``(counts, flat values)``.

    Raises
    ------
    InputError
        Missing or unreadable file, no ``ply`` magic or ``end_header`` line, a bad
        header line, or a body that is truncated or holds something other than the
        numbers the header declares (a negative list length, text in an ASCII row, a
        non-integer value of an integer property).
    """
    path = Path(path)
    if data is None:
        data = read_bytes(path)
    header, declared, body = _parse_header(path, data)
    wanted = {e.name for e in declared} if elements is None else set(elements)
    stop = max((i + 1 for i, e in enumerate(declared) if e.name in wanted), default=0)
    endian = PLY_FORMATS[header.format]
    out: dict[str, PlyElement] = {}
    if endian is None:
        tokens, pos = data[body:].split(), 0
    else:
        tokens, pos = None, body
    for element in declared[:stop]:
        keep = element.name in wanted
        if tokens is None:
            values, pos = _binary_element(path, data, pos, element, endian, keep)
        else:
            values, pos = _ascii_element(path, tokens, pos, element, keep)
        if keep:
            out[element.name] = PlyElement(element.name, element.count, values)
    return PlyData(header, out)


def read_ply_header(path: str | Path, data: bytes | None = None) -> PlyHeader:
    """Parse only the header of a PLY file (arguments and errors as :func:`read_ply`)."""
    path = Path(path)
    return _parse_header(path, read_bytes(path) if data is None else data)[0]


def read_ply_types(
    path: str | Path, data: bytes | None = None
) -> dict[str, tuple[tuple[str, np.dtype, np.dtype | None], ...]]:
    """Every element's properties as declared: ``(name, value dtype, list count dtype or
    None)`` in header order (what a writer needs to write a file back with its types)."""
    path = Path(path)
    declared = _parse_header(path, read_bytes(path) if data is None else data)[1]
    return {e.name: tuple((p.name, p.dtype, p.count_dtype) for p in e.properties) for e in declared}


def read_bytes(path: str | Path) -> bytes:
    """A file's contents, or an :class:`InputError` saying why they cannot be read."""
    path = check_input_file(path, "PLY file")
    try:
        return path.read_bytes()
    except OSError as exc:
        raise InputError(path, f"cannot read ({exc.strerror or exc})") from exc


def _fail(path: Path, problem: str) -> InputError:
    return InputError(path, _PREFIX + problem)


# -- header ----------------------------------------------------------------------------


def _parse_header(path: Path, data: bytes) -> tuple[PlyHeader, list[_Element], int]:
    """The header, its element declarations and the offset where the body starts."""
    if not re.match(rb"ply[ \t]*(?:\r\n|\n|\r)", data):
        raise _fail(path, "not a PLY file (no 'ply' magic)")
    end = _END_HEADER.search(data, 0, _MAX_HEADER_BYTES)
    if end is None:
        raise _fail(path, "not a PLY file (no 'end_header' line)")
    try:
        text = data[: end.start()].decode("ascii")
    except UnicodeDecodeError:
        text = data[: end.start()].decode("latin-1")  # names and comments of legacy tools
    fmt = None
    declared: list[tuple[str, int, list[_Property]]] = []
    comments: list[str] = []
    for line in re.split(r"\r\n|\r|\n", text)[1:]:
        words = line.split()
        if not words:
            continue
        if words[0] in ("comment", "obj_info"):
            if words[0] == "comment":
                comments.append(line.strip()[len("comment") :].strip())
            continue
        try:
            _header_line(words, declared)
            if words[0] == "format":
                fmt = words[1]
        except (IndexError, ValueError) as exc:
            reason = "too few words" if isinstance(exc, IndexError) else str(exc)
            raise _fail(path, f"bad PLY header line {line.strip()[:60]!r} ({reason})") from None
    if fmt is None:
        raise _fail(path, "header has no 'format' line")
    elements = [_Element(name, count, tuple(props)) for name, count, props in declared]
    summary = {e.name: (e.count, tuple(p.name for p in e.properties)) for e in elements}
    return PlyHeader(fmt, summary, tuple(comments)), elements, end.end()


def _header_line(words: list[str], declared: list) -> None:
    """Check one ``format``/``element``/``property`` line; append what it declares."""
    key = words[0]
    if key == "format":
        if words[1] not in PLY_FORMATS:
            raise ValueError(f"unsupported format {words[1]!r}")
    elif key == "element":
        count = int(words[2])
        if count < 0:
            raise ValueError(f"negative count {count}")
        if any(words[1] == name for name, _, _ in declared):
            raise ValueError(f"element {words[1]!r} declared twice")
        declared.append((words[1], count, []))
    elif key == "property":
        if not declared:
            raise ValueError("property before any element")
        if words[1] == "list":
            name, item, counter = words[4], _ply_dtype(words[3]), _ply_dtype(words[2])
            if counter.kind not in "iu":
                raise ValueError(f"list count type {words[2]!r} is not an integer type")
        else:
            name, item, counter = words[2], _ply_dtype(words[1]), None
        props = declared[-1][2]
        if any(p.name == name for p in props):
            raise ValueError(f"property {name!r} declared twice")
        props.append(_Property(name, item, counter))
    else:
        raise ValueError(f"unknown keyword {key!r}")


def _ply_dtype(name: str) -> np.dtype:
    try:
        return np.dtype(PLY_TYPES[name])
    except KeyError:
        raise ValueError(f"unknown type {name!r}") from None


# -- shared by both encodings ----------------------------------------------------------
# Positions count "units": bytes in a binary body, tokens in an ASCII one.


def _truncated(path: Path, element: _Element) -> InputError:
    problem = f"file ends before its {element.count} {element.name} elements (truncated)"
    return _fail(path, problem)


def _negative(path: Path, element: _Element) -> InputError:
    return _fail(path, f"negative list length in element {element.name!r}")


def _walk(path: Path, element: _Element, pos: int, limit: int, size, reader, rows: int):
    """``(list lengths (rows, lists) int64, end position)`` of the first ``rows`` rows.

    Walks row by row in Python, reading only the list lengths: ``reader(prop)`` gives a
    function reading one at a position, ``size(dtype)`` is one value's size in units and
    ``limit`` the body's end.
    """
    plan, fixed = [], 0  # per list: units of scalars before it, reader, sizes
    for prop in element.properties:
        if prop.count_dtype is None:
            fixed += size(prop.dtype)
        else:
            plan.append((fixed, reader(prop), size(prop.count_dtype), size(prop.dtype)))
            fixed = 0
    counts: list[int] = []
    append = counts.append
    try:
        for _ in range(rows):
            for before, read, count_size, item_size in plan:
                pos += before
                n = read(pos)
                if n < 0:
                    raise _negative(path, element)
                append(n)
                pos += count_size + n * item_size
            pos += fixed
    except (IndexError, struct.error):
        raise _truncated(path, element) from None
    if pos > limit:
        raise _truncated(path, element)
    return np.array(counts, dtype=np.int64).reshape(rows, len(plan)), pos


def _labels(element: _Element, counts: np.ndarray, size) -> np.ndarray:
    """The property index each unit of the rows belongs to (-1: a list length), given the
    (rows, lists) list lengths and ``size(dtype)``, one value's size in units."""
    rows = len(counts)
    sizes, labels, k = [], [], 0
    for i, prop in enumerate(element.properties):
        if prop.count_dtype is None:
            sizes.append(np.full(rows, size(prop.dtype)))
            labels.append(i)
        else:
            sizes += [np.full(rows, size(prop.count_dtype)), counts[:, k] * size(prop.dtype)]
            labels += [-1, i]
            k += 1
    kind = np.int8 if len(labels) < 127 else np.int32
    return np.repeat(np.tile(np.array(labels, kind), rows), np.stack(sizes, axis=1).ravel())


def _columns(element: _Element, counts: np.ndarray, column) -> dict:
    """``{name: array or PlyList}`` from the (rows, lists) list lengths and
    ``column(index, property)``, which returns a property's values, flat."""
    values: dict = {}
    k = 0
    for i, prop in enumerate(element.properties):
        if prop.count_dtype is None:
            values[prop.name] = column(i, prop)
        else:
            values[prop.name] = PlyList(np.ascontiguousarray(counts[:, k]), column(i, prop))
            k += 1
    return values


def _uniform_counts(element: _Element, first: np.ndarray, list_column) -> np.ndarray | None:
    """(rows, lists) list lengths when every row's equal the first row's, else None;
    ``list_column(k)`` is the k-th list's length in every row."""
    for k in range(first.shape[1]):
        if not (list_column(k) == first[0, k]).all():
            return None
    return np.repeat(first, element.count, axis=0)


def _empty(element: _Element, float_dtype=None) -> dict:
    """Columns of an element with no rows."""
    lists = sum(p.count_dtype is not None for p in element.properties)

    def column(i, prop):
        return np.zeros(0, float_dtype if float_dtype and prop.dtype.kind == "f" else prop.dtype)

    return _columns(element, np.zeros((0, lists), np.int64), column)


# -- binary ----------------------------------------------------------------------------


def _binary_element(
    path: Path, data: bytes, pos: int, element: _Element, endian: str, keep: bool
):
    """One element's columns (None unless ``keep``) and the byte offset after it."""
    props, count = element.properties, element.count
    if count == 0 or not props:
        return (_empty(element) if keep else None), pos

    def reader(prop):
        unpack = struct.Struct(endian + prop.count_dtype.char).unpack_from
        return lambda at: unpack(data, at)[0]

    def size(dtype):
        return dtype.itemsize

    first, _ = _walk(path, element, pos, len(data), size, reader, rows=1)
    fields, k = [], 0
    for i, prop in enumerate(props):
        if prop.count_dtype is not None:
            fields.append((f"c{i}", prop.count_dtype.newbyteorder(endian)))
            fields.append((f"p{i}", prop.dtype.newbyteorder(endian), (int(first[0, k]),)))
            k += 1
        else:
            fields.append((f"p{i}", prop.dtype.newbyteorder(endian)))
    row = np.dtype(fields)
    end = pos + count * row.itemsize
    if end <= len(data):
        # fast path: one structured read, valid when every row has the first row's lengths
        table = np.frombuffer(data, row, count, pos)
        names = [f"c{i}" for i, p in enumerate(props) if p.count_dtype is not None]
        counts = _uniform_counts(element, first, lambda k: table[names[k]])
        if counts is not None:
            if not keep:
                return None, end
            values = _columns(element, counts, lambda i, p: table[f"p{i}"].astype(p.dtype).ravel())
            return values, end
    elif first.shape[1] == 0:
        raise _truncated(path, element)
    # list lengths vary: walk the rows for the lengths, then gather the values with numpy
    counts, end = _walk(path, element, pos, len(data), size, reader, rows=count)
    if not keep:
        return None, end
    raw = np.frombuffer(data, np.uint8, end - pos, pos)
    labels = _labels(element, counts, size)

    def column(i, prop):
        return raw[labels == i].view(prop.dtype.newbyteorder(endian)).astype(prop.dtype)

    return _columns(element, counts, column), end


# -- ASCII -----------------------------------------------------------------------------


def _ascii_element(path: Path, tokens: list[bytes], pos: int, element: _Element, keep: bool):
    """One element's columns (None unless ``keep``) and the token index after it.

    Rows are read as a stream of whitespace-separated numbers, so a row wrapped over
    several lines still reads.
    """
    props, count = element.properties, element.count
    if count == 0 or not props:
        return (_empty(element, np.float64) if keep else None), pos

    def reader(prop):
        def read(at: int) -> int:
            token = tokens[at]
            try:
                return int(token)
            except ValueError:
                return _ascii_count(path, element, token)

        return read

    def size(dtype):
        return 1

    first, _ = _walk(path, element, pos, len(tokens), size, reader, rows=1)
    has_lists = first.shape[1] > 0
    widths = [1 + (int(first[0, k]) if k is not None else 0) for k in _list_index(props)]
    starts = np.cumsum([0] + widths)
    end = pos + count * int(starts[-1])
    if not has_lists and end > len(tokens):
        raise _truncated(path, element)
    if not keep and not has_lists:
        return None, end
    if keep and end <= len(tokens):
        # fast path: a (rows, width) table, valid when every row has the first row's lengths
        try:
            table = np.array(tokens[pos:end], dtype=bytes).astype(np.float64)
        except ValueError:
            if not has_lists:
                _ascii_numbers(path, element, tokens[pos:end])  # raises, naming the token
            table = None  # lengths vary and the span reaches past the element: walk below
        if table is not None:
            table = table.reshape(count, -1)
            at = [starts[i] for i, k in enumerate(_list_index(props)) if k is not None]
            counts = _uniform_counts(element, first, lambda k: table[:, at[k]])
            if counts is not None:

                def cell(i, prop):
                    start = starts[i] + (prop.count_dtype is not None)
                    flat = np.ascontiguousarray(table[:, start : starts[i + 1]]).ravel()
                    return _ascii_typed(path, element, prop, flat)

                return _columns(element, counts, cell), end
    counts, end = _walk(path, element, pos, len(tokens), size, reader, rows=count)
    if not keep:
        return None, end
    numbers = _ascii_numbers(path, element, tokens[pos:end])
    labels = _labels(element, counts, size)

    def column(i, prop):
        return _ascii_typed(path, element, prop, numbers[labels == i])

    return _columns(element, counts, column), end


def _list_index(props) -> list[int | None]:
    """For each property, its index among the list properties (None for scalars)."""
    out, k = [], 0
    for prop in props:
        out.append(None if prop.count_dtype is None else k)
        k += prop.count_dtype is not None
    return out


def _bad_ascii(path: Path, element: _Element, problem: str) -> InputError:
    return _fail(path, f"bad ASCII data in element {element.name!r}: {problem}")


def _ascii_count(path: Path, element: _Element, token: bytes) -> int:
    """A list length written as a float (``3.0``); fractions and text raise."""
    try:
        value = float(token)
    except ValueError:
        raise _bad_ascii(path, element, f"{_shown(token)} is not a number") from None
    if not value.is_integer():
        raise _bad_ascii(path, element, f"list length {_shown(token)} is not an integer")
    return int(value)


def _ascii_numbers(path: Path, element: _Element, tokens: list[bytes]) -> np.ndarray:
    """Tokens as float64, or the one-line error naming the first that is not a number."""
    try:
        return np.array(tokens, dtype=bytes).astype(np.float64)
    except ValueError as exc:
        for token in tokens:
            try:
                float(token)
            except ValueError:
                raise _bad_ascii(path, element, f"{_shown(token)} is not a number") from None
        raise _bad_ascii(path, element, str(exc)) from None


def _ascii_typed(path: Path, element: _Element, prop: _Property, values: np.ndarray):
    """ASCII values of a property: floats as read (float64), integers checked and cast."""
    if prop.dtype.kind == "f":
        return values
    info = np.iinfo(prop.dtype)
    ok = (values == np.round(values)) & (values >= info.min) & (values <= info.max)
    if not ok.all():
        problem = f"property {prop.name!r} ({prop.dtype}) holds {values[~ok][0]:g}"
        raise _bad_ascii(path, element, problem)
    return values.astype(prop.dtype)


def _shown(token: bytes) -> str:
    return repr(token[:20].decode("latin-1"))
