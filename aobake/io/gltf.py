"""glTF/GLB out: a glTF input's own document with ``_AO`` added per primitive, or a new
document of the meshes for other inputs.

The document is edited as JSON plus its binary buffers, so whatever aobake does not
know (materials, textures, skins, animations, cameras, extensions, extras) passes
through untouched. Only new accessors, buffer views and, for a mesh instanced by several
nodes, mesh entries are added. Reading meshes for the bake stays with trimesh
(:mod:`aobake.io.trimesh_formats`); this module decodes just enough of the document
(positions and colours) to find which primitive each baked part came from.

Imports numpy only.
"""

from __future__ import annotations

import base64
import copy
import json
import logging
import os
import struct
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote, unquote

import numpy as np

from ..errors import InputError, NumericalError, OutputError
from .color import CHANNELS, quantize, srgb_to_linear
from .common import atomic_write, check_ao, check_attributes, check_display

log = logging.getLogger(__name__)

#: glTF componentType -> numpy type code (little-endian in the buffers).
COMPONENTS = {5120: "i1", 5121: "u1", 5122: "i2", 5123: "u2", 5125: "u4", 5126: "f4"}
#: numpy type code -> glTF componentType.
COMPONENT_TYPES = {code: key for key, code in COMPONENTS.items()}
#: Values per element of each accessor type.
WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
#: Primitive modes trimesh reads as triangles (TRIANGLES, TRIANGLE_STRIP).
TRIANGLE_MODES = (4, 5)

_GLB_MAGIC, _JSON_CHUNK, _BIN_CHUNK = b"glTF", 0x4E4F534A, 0x004E4942
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_MIME = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".webp": "image/webp",
         ".ktx2": "image/ktx2"}  # fmt: skip


@dataclass
class Document:
    """A glTF document as read: its JSON, every buffer's bytes, where it came from."""

    json: dict
    buffers: list[bytes]
    path: Path
    glb: bool


@dataclass(frozen=True)
class Slot:
    """One triangle primitive placed by one node, in scene order."""

    node: int
    mesh: int
    primitive: int
    positions: np.ndarray  # (n, 3) float64, world space


def read_document(path: str | Path) -> Document:
    """Parse a ``.gltf`` (buffers as data URIs or files beside it) or a ``.glb``."""
    path = Path(path)
    data = path.read_bytes()
    binary = None
    if data[:4] == _GLB_MAGIC:
        version, length = struct.unpack_from("<II", data, 4)
        if version != 2:
            raise InputError(
                path, f"cannot read as glTF: GLB version {version}, only 2 is supported"
            )
        pos, doc = 12, None
        while pos + 8 <= min(length, len(data)):
            size, kind = struct.unpack_from("<II", data, pos)
            chunk = data[pos + 8 : pos + 8 + size]
            if kind == _JSON_CHUNK and doc is None:
                doc = json.loads(chunk)
            elif kind == _BIN_CHUNK and binary is None:
                binary = chunk
            pos += 8 + size
        if doc is None:
            raise InputError(path, "cannot read as glTF: GLB has no JSON chunk")
    else:
        doc = json.loads(data)
    buffers = []
    for i, buffer in enumerate(doc.get("buffers", [])):
        uri = buffer.get("uri")
        if uri is None:
            if binary is None or i != 0:
                raise InputError(path, f"cannot read as glTF: buffer {i} has no data")
            buffers.append(binary)
        elif uri.startswith("data:"):
            buffers.append(base64.b64decode(uri.partition(",")[2]))
        else:
            buffers.append((path.parent / unquote(uri)).read_bytes())
    return Document(doc, buffers, path, binary is not None or data[:4] == _GLB_MAGIC)


def accessor_values(doc: Document, index: int) -> np.ndarray:
    """An accessor's elements ``(count, width)`` in its own component type (sparse
    substitution applied, normalisation not)."""
    a = doc.json["accessors"][index]
    dtype = np.dtype("<" + COMPONENTS[a["componentType"]])
    width, count = WIDTHS[a["type"]], int(a["count"])
    out = np.zeros((count, width), dtype=dtype)
    if "bufferView" in a:
        out[:] = _view(doc, a["bufferView"], a.get("byteOffset", 0), dtype, count, width)
    sparse = a.get("sparse")
    if sparse:
        n = int(sparse["count"])
        idx = sparse["indices"]
        where = _view(
            doc,
            idx["bufferView"],
            idx.get("byteOffset", 0),
            np.dtype("<" + COMPONENTS[idx["componentType"]]),
            n,
            1,
        )[:, 0]
        values = sparse["values"]
        out[where] = _view(doc, values["bufferView"], values.get("byteOffset", 0), dtype, n, width)
    return out


def _view(doc: Document, view_index: int, offset: int, dtype: np.dtype, count: int, width: int):
    view = doc.json["bufferViews"][view_index]
    data = doc.buffers[view["buffer"]]
    start = view.get("byteOffset", 0) + offset
    stride = view.get("byteStride") or dtype.itemsize * width
    if count and start + stride * (count - 1) + dtype.itemsize * width > len(data):
        raise InputError(
            doc.path, f"cannot read as glTF: buffer view {view_index} is shorter than its accessor"
        )
    return np.ndarray((count, width), dtype, data, start, (stride, dtype.itemsize)).copy()


def as_float(values: np.ndarray, normalized: bool) -> np.ndarray:
    """Accessor values as float64, normalised integers mapped to [0, 1] or [-1, 1]."""
    out = values.astype(np.float64)
    if normalized and values.dtype.kind in "iu":
        top = float(np.iinfo(values.dtype).max)
        out = np.maximum(out / top, -1.0)
    return out


def _local_matrix(node: dict) -> np.ndarray:
    """A node's (4, 4) column-vector transform: ``matrix`` or T * R * S."""
    if "matrix" in node:
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T
    x, y, z, w = node.get("rotation", (0.0, 0.0, 0.0, 1.0))
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    m = np.eye(4)
    m[:3, :3] = rotation * np.asarray(node.get("scale", (1.0, 1.0, 1.0)), dtype=np.float64)
    m[:3, 3] = node.get("translation", (0.0, 0.0, 0.0))
    return m


def scene_slots(doc: Document) -> list[Slot]:
    """Every triangle primitive of the default scene, depth-first in the file's node
    order (children as listed), with its world positions: the order trimesh's parts
    take (:func:`aobake.io.trimesh_formats.read_parts`)."""
    gl = doc.json
    nodes, scenes = gl.get("nodes", []), gl.get("scenes", [])
    roots = scenes[gl.get("scene", 0)].get("nodes", []) if scenes else []
    slots: list[Slot] = []
    seen: set[int] = set()
    stack = [(index, np.eye(4)) for index in reversed(roots)]
    while stack:
        index, parent = stack.pop()
        if index in seen or not 0 <= index < len(nodes):
            continue
        seen.add(index)
        node = nodes[index]
        world = parent @ _local_matrix(node)
        if "mesh" in node:
            for k, primitive in enumerate(gl["meshes"][node["mesh"]].get("primitives", [])):
                if primitive.get(
                    "mode", 4
                ) not in TRIANGLE_MODES or "POSITION" not in primitive.get("attributes", {}):
                    continue
                a = primitive["attributes"]["POSITION"]
                local = as_float(
                    accessor_values(doc, a), gl["accessors"][a].get("normalized", False)
                )
                slots.append(Slot(index, node["mesh"], k, local @ world[:3, :3].T + world[:3, 3]))
        stack.extend((child, world) for child in reversed(node.get("children", [])))
    return slots


def match_parts(doc: Document, surface, *, warn: bool = True) -> list[tuple[Slot, object]]:
    """``(slot, part)`` for every part of ``surface``: the first unused slot with the
    part's vertex count and world positions (to float32 precision). ``warn``: log how
    many triangle primitives no part matched (they get no ``_AO``)."""
    slots = scene_slots(doc)
    used = [False] * len(slots)
    pairs, cursor = [], 0
    for part in surface.parts:
        positions = surface.positions[part.vertex_start : part.vertex_stop]
        scale = max(1.0, float(np.abs(positions).max(initial=0.0)))
        # parts come in scene order: the next slot is the one, unless trimesh skipped some
        for i in [*range(cursor, len(slots)), *range(cursor)]:
            slot = slots[i]
            if used[i] or slot.positions.shape != positions.shape:
                continue
            if np.allclose(slot.positions, positions, rtol=0.0, atol=1e-5 * scale):
                used[i], cursor = True, i + 1
                pairs.append((slot, part))
                break
        else:
            raise OutputError(
                f"{doc.path.name}: mesh {part.name!r} matches no primitive of the glTF document; cannot write glTF"
            )
    skipped = len(slots) - sum(used)
    if skipped and warn:
        log.warning("%s: %d primitives were not baked and get no _AO", doc.path.name, skipped)
    return pairs


def read_ao_gltf(path: str | Path) -> np.ndarray:
    """The ``_AO`` of every triangle primitive of the default scene, in the order
    :func:`aobake.io.load_mesh` gives the parts (float64, one value per vertex).

    Raises
    ------
    InputError
        Unreadable file, or a triangle primitive without ``_AO``.
    """
    path = Path(path)
    try:
        doc = read_document(path)
        slots = scene_slots(doc)
    except InputError:
        raise
    except (OSError, ValueError, KeyError, IndexError, TypeError) as exc:
        raise InputError(path, f"cannot read as glTF: {exc}") from exc
    values = []
    for slot in slots:
        attributes = doc.json["meshes"][slot.mesh]["primitives"][slot.primitive]["attributes"]
        if "_AO" not in attributes:
            name = doc.json["nodes"][slot.node].get("name", slot.node)
            raise InputError(path, f"node {name!r} has a primitive without _AO")
        a = attributes["_AO"]
        values.append(
            as_float(accessor_values(doc, a), doc.json["accessors"][a].get("normalized", False))[
                :, 0
            ]
        )
    return np.concatenate(values) if values else np.zeros(0)


def check_images(doc: Document) -> None:
    """Raise :class:`InputError` for an image file the document refers to but that is
    missing (a GLB output embeds them)."""
    for image in doc.json.get("images", []):
        uri = image.get("uri")
        if uri and not uri.startswith("data:") and not (doc.path.parent / unquote(uri)).is_file():
            raise InputError(doc.path, f"image {uri!r} not found; a GLB output embeds its images")


def check_channel(doc: Document, channel: str) -> None:
    """Raise :class:`InputError` unless every triangle primitive has ``COLOR_0``."""
    bare = {(s.mesh, s.primitive) for s in scene_slots(doc) if "COLOR_0" not in
            doc.json["meshes"][s.mesh]["primitives"][s.primitive]["attributes"]}  # fmt: skip
    if bare:
        raise InputError(
            doc.path,
            f"--channel {channel}: {len(bare)} primitives have no vertex colours (COLOR_0)",
        )


class _Blob:
    """New binary data for a document: 4-byte aligned views, accessors pointing at them."""

    def __init__(self, gl: dict, buffer: int):
        self.gl, self.buffer, self.data = gl, buffer, bytearray()

    def view(self, raw: bytes, target: int | None = None) -> int:
        self.data += b"\0" * (-len(self.data) % 4)
        view = {"buffer": self.buffer, "byteOffset": len(self.data), "byteLength": len(raw)}
        if target is not None:
            view["target"] = target
        self.data += raw
        self.gl.setdefault("bufferViews", []).append(view)
        return len(self.gl["bufferViews"]) - 1

    def accessor(self, values: np.ndarray, *, normalized: bool = False, target: int = _ARRAY_BUFFER,
                 bounds: bool = False) -> int:  # fmt: skip
        values = np.ascontiguousarray(values)
        width = 1 if values.ndim == 1 else values.shape[1]
        kind = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}[width]
        code = values.dtype.str[1:]
        a = {
            "bufferView": self.view(values.astype("<" + code).tobytes(), target),
            "componentType": COMPONENT_TYPES[code],
            "count": int(values.shape[0]),
            "type": kind,
        }
        if normalized:
            a["normalized"] = True
        if bounds and len(values):
            flat = values.reshape(len(values), width)
            a["min"] = [v.item() for v in flat.min(axis=0)]
            a["max"] = [v.item() for v in flat.max(axis=0)]
        self.gl.setdefault("accessors", []).append(a)
        return len(self.gl["accessors"]) - 1


def write_gltf(
    path: str | Path,
    surface,
    ao,
    *,
    color: bool = False,
    channel: str | None = None,
    up_axis: str = "Y",
    meters_per_unit: float = 1.0,
    custom_data: dict | None = None,
    attributes=None,
    display=None,
) -> None:
    """Write ``ao`` as glTF (``.gltf``) or GLB (``.glb``), chosen by the suffix.

    A glTF input (``surface.metadata["gltf_path"]``) is written back as its own
    document with, on every baked primitive, the float vertex attribute ``_AO`` and,
    with ``color``, ``COLOR_0`` (linear grey, float32 VEC3, replacing any COLOR_0).
    ``channel`` instead writes ``ao`` into that channel of the primitive's own
    ``COLOR_0`` (same component type; a VEC3 gains an alpha for ``"A"``). A mesh used
    by several nodes is given one copy per further node, sharing every accessor but
    ``_AO`` and ``COLOR_0``: each instance keeps its own AO. Other inputs get a new
    document: one node and mesh per part with POSITION, NORMAL, triangle indices,
    ``_AO`` (and ``COLOR_0``), a PLY input's UVs and colours too, under a root node
    turning Z-up into glTF's Y-up and scaling to metres. Provenance goes into
    ``asset.extras.aobake``.

    ``attributes`` (name -> values, :func:`aobake.io.common.check_attributes`) become
    float application attributes ``_NAME`` (upper case: ``_BENTNORMAL``, VEC3;
    ``_IRRADIANCE``, VEC3 linear; a float, SCALAR) beside ``_AO``. ``display``, linear
    ``(n, 3)`` colours, is what ``color`` writes as ``COLOR_0`` instead of grey.

    Raises
    ------
    NumericalError
        ``ao``, ``attributes`` or ``display`` is non-finite, out of range or not one
        value per vertex; two attribute names the same in upper case.
    InputError
        ``channel`` on a primitive (or a non-glTF input) without vertex colours.
    OutputError
        A baked mesh cannot be found in the source document, or the file cannot be written.
    """
    path = Path(path)
    ao32 = check_ao(ao, n_vertices=surface.n_vertices, where=path.name)
    extras = _extras(attributes, display, surface, path)
    source = surface.metadata.get("gltf_path")
    if source is not None:
        doc = read_document(source)
        gl = copy.deepcopy(doc.json)
        blob = _Blob(gl, len(gl.setdefault("buffers", [])))
        _add_ao(doc, gl, blob, surface, ao32, color=color, channel=channel, extras=extras)
    elif channel is not None and not ply_has_colors(surface):
        raise InputError(
            surface.source, f"--channel {channel}: the mesh has no vertex colours to write into"
        )
    else:
        doc = None
        gl = {"asset": {"version": "2.0"}, "buffers": []}
        blob = _Blob(gl, 0)
        _new_document(
            gl,
            blob,
            surface,
            ao32,
            color=color,
            channel=channel,
            up_axis=up_axis,
            meters_per_unit=meters_per_unit,
            extras=extras,
        )
    asset = gl.setdefault("asset", {"version": "2.0"})
    extras = asset.setdefault("extras", {})
    if isinstance(extras, dict) and custom_data:
        extras["aobake"] = {
            k: v if isinstance(v, (str, int, float, bool)) else str(v)
            for k, v in custom_data.items()
        }
    if path.suffix.lower() == ".glb":
        data = _glb_bytes(doc, gl, blob)
    else:
        data = _gltf_bytes(doc, gl, blob, path)
    try:
        with atomic_write(path) as tmp:
            tmp.write_bytes(data)
    except OSError as exc:
        raise OutputError(f"{path.name}: cannot write ({exc.strerror or exc})") from exc


def attribute_name(name: str) -> str:
    """The glTF application attribute of an extra attribute: ``_`` + upper case."""
    return "_" + name.upper()


def _extras(attributes, display, surface, path: Path):
    """Checked extra attributes keyed by their glTF names, and display colours."""
    n = surface.n_vertices
    checked = check_attributes(attributes, n, path.name)
    named = {attribute_name(name): values for name, (_, values) in checked.items()}
    if len(named) != len(checked) or "_AO" in named:
        raise NumericalError(f"{path.name}: attribute names {sorted(checked)} clash in glTF's upper case")
    return named, check_display(display, n, path.name)


def _put_extras(blob: _Blob, attributes: dict, extras, s: slice, color: bool, ao_values) -> None:
    """The extra attributes' accessors and, with ``color``, COLOR_0 (display or grey)."""
    named, display = extras
    for key, values in named.items():
        attributes[key] = blob.accessor(values[s])
    if color:
        shown = np.repeat(ao_values[:, None], 3, axis=1) if display is None else display[s]
        attributes["COLOR_0"] = blob.accessor(np.ascontiguousarray(shown, dtype=np.float32))


def _add_ao(
    doc: Document, gl: dict, blob: _Blob, surface, ao32, *, color: bool, channel: str | None,
    extras=({}, None),
) -> None:  # fmt: skip
    """``_AO`` (and colours) on every matched primitive; instanced meshes copied per node."""
    owner: dict[int, int] = {}  # source mesh -> the node that keeps it
    node_mesh: dict[int, int] = {}  # node -> the mesh it now uses
    for slot, part in match_parts(doc, surface):
        values = ao32[part.vertex_start : part.vertex_stop]
        if slot.node not in node_mesh:
            if owner.setdefault(slot.mesh, slot.node) == slot.node:
                node_mesh[slot.node] = slot.mesh
            else:  # an instance: its own copy of the mesh, sharing the source's accessors
                gl["meshes"].append(copy.deepcopy(doc.json["meshes"][slot.mesh]))
                node_mesh[slot.node] = gl["nodes"][slot.node]["mesh"] = len(gl["meshes"]) - 1
        primitive = gl["meshes"][node_mesh[slot.node]]["primitives"][slot.primitive]
        attributes = primitive["attributes"]
        attributes["_AO"] = blob.accessor(values, bounds=True)
        if channel is not None:
            attributes["COLOR_0"] = _packed_colors(
                doc, blob, attributes.get("COLOR_0"), values, channel
            )
        _put_extras(blob, attributes, extras, slice(part.vertex_start, part.vertex_stop),
                    color and channel is None, values)  # fmt: skip


def _packed_colors(doc: Document, blob: _Blob, index: int | None, values, channel: str) -> int:
    """A new COLOR_0 accessor: the source's colours with ``values`` in one channel."""
    if index is None:
        raise InputError(
            doc.path, f"--channel {channel}: a primitive has no vertex colours (COLOR_0)"
        )
    a = doc.json["accessors"][index]
    colors = accessor_values(doc, index)
    column = CHANNELS[channel]
    if column >= colors.shape[1]:  # "A" on RGB colours: an alpha column to hold the values
        colors = np.column_stack([colors, np.zeros(len(colors), dtype=colors.dtype)])
    colors[:, column] = quantize(values, colors.dtype)
    return blob.accessor(colors, normalized=a.get("normalized", False))


#: PLY texture-coordinate property pairs, in the order they are looked for.
PLY_UV_NAMES = (("s", "t"), ("u", "v"), ("texture_u", "texture_v"), ("texture_s", "texture_t"))


def ply_has_colors(surface) -> bool:
    """True when the surface is a PLY input with ``red green blue`` vertex colours."""
    kept = surface.metadata.get("ply")
    columns = {} if kept is None else kept.data.elements["vertex"].properties
    return len(surface.parts) == 1 and all(
        isinstance(columns.get(c), np.ndarray) for c in ("red", "green", "blue")
    )


def _ply_attributes(blob: _Blob, surface, part, channel: str | None) -> dict:
    """A PLY input's UVs (``TEXCOORD_0``, v flipped to glTF's top-left origin) and colours
    (``COLOR_0`` values, not yet an accessor). Colours: 8-bit sRGB bytes become linear
    floats (the grey a viewer showed stays the same); with ``channel`` they stay the
    stored numbers (normalised integers), since packed channels are data."""
    kept = surface.metadata.get("ply")
    if kept is None or len(surface.parts) != 1:
        return {}
    columns = kept.data.elements["vertex"].properties
    out: dict = {}
    for u, v in PLY_UV_NAMES:
        if isinstance(columns.get(u), np.ndarray) and isinstance(columns.get(v), np.ndarray):
            uv = np.column_stack([columns[u], 1.0 - np.asarray(columns[v], dtype=np.float64)])
            out["TEXCOORD_0"] = blob.accessor(uv.astype(np.float32))
            break
    if not ply_has_colors(surface):
        return out
    names = [c for c in ("red", "green", "blue", "alpha") if isinstance(columns.get(c), np.ndarray)]
    stored = np.column_stack([columns[c] for c in names])
    if channel is not None and CHANNELS[channel] >= stored.shape[1]:
        stored = np.column_stack([stored, np.zeros(len(stored), dtype=stored.dtype)])
    scale = float(np.iinfo(stored.dtype).max) if stored.dtype.kind in "iu" else 1.0
    if channel is not None:  # glTF colours are ubyte, ushort or float
        ok = stored.dtype in (np.uint8, np.uint16)
        out["COLOR_0"] = stored if ok else np.clip(stored / scale, 0.0, 1.0).astype(np.float32)
        return out
    linear = np.clip(stored / scale, 0.0, 1.0)
    linear[:, :3] = srgb_to_linear(linear[:, :3])  # alpha is not a colour: kept linear
    out["COLOR_0"] = linear.astype(np.float32)
    return out


def _new_document(
    gl, blob, surface, ao32, *, color, channel, up_axis, meters_per_unit, extras=({}, None)
) -> None:
    """One node, mesh and primitive per part, positions relative to the part's centre; a
    PLY input's UVs and colours come along (:func:`_ply_attributes`)."""
    children = []
    gl["meshes"], gl["nodes"] = [], []
    for part in surface.parts:
        s = slice(part.vertex_start, part.vertex_stop)
        positions = surface.positions[s]
        centre = 0.5 * (positions.min(axis=0) + positions.max(axis=0))
        attributes = {
            "POSITION": blob.accessor((positions - centre).astype(np.float32), bounds=True)
        }
        normals = surface.normals[s]
        if np.abs(np.linalg.norm(normals, axis=1) - 1.0).max(initial=0.0) < 1e-3:  # glTF: unit only
            attributes["NORMAL"] = blob.accessor(normals.astype(np.float32))
        attributes.update(_ply_attributes(blob, surface, part, channel))
        attributes["_AO"] = blob.accessor(ao32[s], bounds=True)
        if channel is not None:
            colors = attributes.pop("COLOR_0")
            colors[:, CHANNELS[channel]] = quantize(ao32[s], colors.dtype)
            attributes["COLOR_0"] = blob.accessor(colors, normalized=colors.dtype.kind == "u")
        elif not color and "COLOR_0" in attributes:
            attributes["COLOR_0"] = blob.accessor(attributes["COLOR_0"])
        _put_extras(blob, attributes, extras, s, color and channel is None, ao32[s])
        faces = surface.faces[part.face_start : part.face_stop] - part.vertex_start
        indices = blob.accessor(faces.reshape(-1).astype(np.uint32), target=_ELEMENT_ARRAY_BUFFER)
        gl["meshes"].append(
            {"name": part.name, "primitives": [{"attributes": attributes, "indices": indices}]}
        )
        gl["nodes"].append(
            {"name": part.name, "mesh": len(gl["meshes"]) - 1, "translation": centre.tolist()}
        )
        children.append(len(gl["nodes"]) - 1)
    root = {"name": Path(surface.source).stem or "aobake", "children": children}
    if up_axis == "Z":  # -90 degrees about x: +Z becomes glTF's +Y
        root["rotation"] = [-np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)]
    if meters_per_unit != 1.0:
        root["scale"] = [float(meters_per_unit)] * 3
    gl["nodes"].append(root)
    gl["scenes"], gl["scene"] = [{"nodes": [len(gl["nodes"]) - 1]}], 0


def _pad(data: bytes, fill: bytes) -> bytes:
    return data + fill * (-len(data) % 4)


def _glb_bytes(doc: Document | None, gl: dict, blob: _Blob) -> bytes:
    """One GLB: every buffer and file-referenced image moved into the one BIN chunk."""
    sources = [] if doc is None else list(doc.buffers)
    sources.append(bytes(blob.data))
    starts, chunk = [], bytearray()
    for data in sources:
        chunk += b"\0" * (-len(chunk) % 16)  # keeps every view's alignment
        starts.append(len(chunk))
        chunk += data
    for view in gl.get("bufferViews", []):
        view["byteOffset"] = view.get("byteOffset", 0) + starts[view["buffer"]]
        view["buffer"] = 0
    for image in gl.get("images", []):
        uri = image.get("uri")
        if uri is None or uri.startswith("data:") or doc is None:
            continue
        file = doc.path.parent / unquote(uri)
        try:
            data = file.read_bytes()
        except OSError as exc:
            raise InputError(
                doc.path, f"cannot read image {uri!r} to embed in the GLB ({exc.strerror or exc})"
            ) from exc
        chunk += b"\0" * (-len(chunk) % 4)
        gl["bufferViews"].append({"buffer": 0, "byteOffset": len(chunk), "byteLength": len(data)})
        chunk += data
        del image["uri"]
        image["bufferView"] = len(gl["bufferViews"]) - 1
        image.setdefault("mimeType", _MIME.get(file.suffix.lower(), "image/png"))
    gl["buffers"] = [{"byteLength": len(chunk)}]
    text = _pad(json.dumps(gl, separators=(",", ":")).encode("utf-8"), b" ")
    binary = _pad(bytes(chunk), b"\0")
    total = 12 + 8 + len(text) + 8 + len(binary)
    return b"".join(
        [
            struct.pack("<4sII", _GLB_MAGIC, 2, total),
            struct.pack("<II", len(text), _JSON_CHUNK),
            text,
            struct.pack("<II", len(binary), _BIN_CHUNK),
            binary,
        ]
    )


def _gltf_bytes(doc: Document | None, gl: dict, blob: _Blob, path: Path) -> bytes:
    """A ``.gltf``: the source's files referenced where they are (relative to ``path``),
    a GLB's BIN and the new data embedded as data URIs, so one file is written."""
    buffers = gl["buffers"]
    if doc is not None:
        for i, buffer in enumerate(buffers[: len(doc.buffers)]):
            buffer["uri"] = _moved(doc, buffer.get("uri"), path) or _data_uri(doc.buffers[i])
        for image in gl.get("images", []):
            if "uri" in image:
                image["uri"] = _moved(doc, image["uri"], path)
    buffers.append({"byteLength": len(blob.data), "uri": _data_uri(bytes(blob.data))})
    return json.dumps(gl, indent=1).encode("utf-8")


def _moved(doc: Document, uri: str | None, path: Path) -> str | None:
    """A file URI of the source, relative to the output's directory (data URIs kept)."""
    if uri is None or uri.startswith("data:"):
        return uri
    target = (doc.path.parent / unquote(uri)).resolve()
    return quote(Path(os.path.relpath(target, path.resolve().parent)).as_posix())


def _data_uri(data: bytes) -> str:
    return "data:application/octet-stream;base64," + base64.b64encode(data).decode("ascii")


def read_colours_gltf(path: str | Path) -> np.ndarray:
    """(n, 3) linear ``COLOR_0`` of every triangle primitive, in :func:`read_ao_gltf`'s order."""
    path = Path(path)
    try:
        doc = read_document(path)
        slots = scene_slots(doc)
    except InputError:
        raise
    except (OSError, ValueError, KeyError, IndexError, TypeError) as exc:
        raise InputError(path, f"cannot read as glTF: {exc}") from exc
    values = []
    for slot in slots:
        attributes = doc.json["meshes"][slot.mesh]["primitives"][slot.primitive]["attributes"]
        if "COLOR_0" not in attributes:
            name = doc.json["nodes"][slot.node].get("name", slot.node)
            raise InputError(path, f"node {name!r} has a primitive without COLOR_0 colours to show")
        a = attributes["COLOR_0"]
        rgb = as_float(accessor_values(doc, a), doc.json["accessors"][a].get("normalized", False))[:, :3]
        values.append(rgb)
    return np.concatenate(values) if values else np.zeros((0, 3))
