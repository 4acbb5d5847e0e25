"""Small glTF assets built by hand (JSON + numpy buffers, no aobake code) and a plain
accessor decoder, for tests/test_io_gltf.py.

The scene: a textured ground quad (material, UVs, a PNG texture) with a second,
point-list primitive; one box mesh placed by two nodes (an instance, one of them
rotated and scaled under a parent with a matrix); a tetrahedron with ubyte ``COLOR_0``;
a material extension, an unknown node extension and extras that must pass through.
"""

from __future__ import annotations

import base64
import json
import struct
import zlib
from pathlib import Path

import numpy as np

COMPONENTS = {5120: "i1", 5121: "u1", 5122: "i2", 5123: "u2", 5125: "u4", 5126: "f4"}
WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def png(rgb) -> bytes:
    """A PNG of an (h, w, 3) uint8 image (filter 0 rows, one IDAT)."""
    rgb = np.asarray(rgb, dtype=np.uint8)
    h, w, _ = rgb.shape
    raw = b"".join(b"\0" + rgb[i].tobytes() for i in range(h))

    def chunk(kind, body):
        return (
            struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
        )

    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)) + \
        chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")  # fmt: skip


TEXTURE = png(np.arange(2 * 2 * 3).reshape(2, 2, 3) * 20)


def box_arrays(h=0.5):
    """24 vertices (4 per side, split normals), UVs, 36 indices, counter-clockwise outside."""
    positions, normals, uvs, indices = [], [], [], []
    eye = np.eye(3)
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = sign * eye[axis]
            u, v = eye[(axis + 1) % 3], eye[(axis + 2) % 3]
            if sign < 0:
                u, v = v, u
            base = len(positions)
            for du, dv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                positions.append(h * (n + du * u + dv * v))
                normals.append(n)
                uvs.append(((du + 1) / 2, (dv + 1) / 2))
            indices += [base, base + 1, base + 2, base, base + 2, base + 3]
    return (np.array(positions, np.float32), np.array(normals, np.float32), np.array(uvs, np.float32),
            np.array(indices, np.uint16))  # fmt: skip


class _Builder:
    def __init__(self):
        self.data = bytearray()
        self.views, self.accessors = [], []

    def add(self, values, *, normalized=False, target=34962):
        values = np.ascontiguousarray(values)
        self.data += b"\0" * (-len(self.data) % 4)
        self.views.append(
            {
                "buffer": 0,
                "byteOffset": len(self.data),
                "byteLength": values.nbytes,
                "target": target,
            }
        )
        self.data += values.tobytes()
        width = 1 if values.ndim == 1 else values.shape[1]
        code = {v: k for k, v in COMPONENTS.items()}[values.dtype.str[1:]]
        a = {"bufferView": len(self.views) - 1, "componentType": code, "count": len(values),
             "type": {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}[width]}  # fmt: skip
        if normalized:
            a["normalized"] = True
        if target == 34962 and width == 3 and values.dtype == np.float32:
            a["min"], a["max"] = values.min(axis=0).tolist(), values.max(axis=0).tolist()
        self.accessors.append(a)
        return len(self.accessors) - 1


def scene_document(*, colored_everywhere: bool = False):
    """The scene's JSON (without buffers/images' storage) and its binary buffer.

    ``colored_everywhere``: every triangle primitive has ``COLOR_0`` (for ``--channel``).
    """
    b = _Builder()
    ground_p = np.array([[-3, 0, -3], [3, 0, -3], [3, 0, 3], [-3, 0, 3]], np.float32)
    ground = {
        "POSITION": b.add(ground_p),
        "NORMAL": b.add(np.tile(np.float32([0, 1, 0]), (4, 1))),
        "TEXCOORD_0": b.add(np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)),
    }
    ground_i = b.add(np.array([0, 2, 1, 0, 3, 2], np.uint16), target=34963)
    points = {"POSITION": b.add(np.array([[0, 2, 0], [0, 3, 0], [1, 3, 0]], np.float32))}
    bp, bn, buv, bi = box_arrays()
    box = {"POSITION": b.add(bp), "NORMAL": b.add(bn), "TEXCOORD_0": b.add(buv)}
    box_i = b.add(bi, target=34963)
    tet_p = np.array([[0, 0, 0], [0.4, 0, 0], [0, 0, 0.4], [0, 0.4, 0]], np.float32)
    tet = {"POSITION": b.add(tet_p),
           "COLOR_0": b.add(np.array([[10, 20, 30, 40], [50, 60, 70, 80], [90, 100, 110, 120], [1, 2, 3, 4]],
                                     np.uint8), normalized=True)}  # fmt: skip
    tet_i = b.add(np.array([0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3], np.uint16), target=34963)
    if colored_everywhere:
        ground["COLOR_0"] = b.add(np.tile(np.float32([0.2, 0.4, 0.6]), (4, 1)))
        box["COLOR_0"] = b.add(np.tile(np.float32([0.9, 0.8, 0.7, 0.5]), (24, 1)))
    s = np.sqrt(0.5)
    gl = {
        "asset": {"version": "2.0", "generator": "tests/gltf_assets.py", "extras": {"kept": 1}},
        "extensionsUsed": ["KHR_materials_emissive_strength", "EXT_test_unknown"],
        "scene": 0,
        "scenes": [{"name": "main", "nodes": [0, 1]}],
        "nodes": [
            {"name": "ground", "mesh": 0},
            {
                "name": "props",
                "matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0.5, 0, 1],
                "children": [3, 2],
                "extras": {"note": "parent"},
            },
            {"name": "box_a", "mesh": 1, "translation": [-1.2, 0, 0]},
            {
                "name": "box_b",
                "mesh": 1,
                "translation": [1.2, -0.1, 0.3],
                "rotation": [0, s, 0, s],
                "scale": [0.8, 0.8, 0.8],
                "extensions": {"EXT_test_unknown": {"x": 1}},
                "children": [4],
            },
            {"name": "tet", "mesh": 2, "translation": [0, 0.5, 0]},
        ],
        "meshes": [
            {
                "name": "ground",
                "primitives": [
                    {"attributes": ground, "indices": ground_i, "material": 0},
                    {"attributes": points, "mode": 0},
                ],
            },  # fmt: skip
            {"name": "box", "primitives": [{"attributes": box, "indices": box_i, "material": 1}]},
            {"name": "tet", "primitives": [{"attributes": tet, "indices": tet_i}]},
        ],
        "materials": [
            {"name": "textured", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}},
            {
                "name": "glow",
                "emissiveFactor": [1, 0.5, 0],
                "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 2.0}},
            },  # fmt: skip
        ],
        "textures": [{"sampler": 0, "source": 0}],
        "samplers": [{"magFilter": 9728}],
        "images": [{"name": "checker"}],
        "accessors": b.accessors,
        "bufferViews": b.views,
        "buffers": [{"byteLength": len(b.data)}],
    }
    return gl, bytes(b.data)


def write_scene(path, *, colored_everywhere: bool = False) -> Path:
    """The scene as ``.glb`` (texture in the BIN chunk) or ``.gltf`` (``NAME.bin`` and
    ``tex ture.png`` beside it: a URI that needs percent-encoding)."""
    path = Path(path)
    gl, data = scene_document(colored_everywhere=colored_everywhere)
    if path.suffix == ".glb":
        data = bytearray(data) + b"\0" * (-len(data) % 4)
        gl["bufferViews"].append({"buffer": 0, "byteOffset": len(data), "byteLength": len(TEXTURE)})
        data += TEXTURE
        gl["images"][0].update(bufferView=len(gl["bufferViews"]) - 1, mimeType="image/png")
        gl["buffers"][0]["byteLength"] = len(data)
        data += b"\0" * (-len(data) % 4)
        text = json.dumps(gl).encode()
        text += b" " * (-len(text) % 4)
        total = 12 + 8 + len(text) + 8 + len(data)
        path.write_bytes(struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<II", len(text), 0x4E4F534A)
                         + text + struct.pack("<II", len(data), 0x004E4942) + bytes(data))  # fmt: skip
    else:
        (path.parent / f"{path.stem}.bin").write_bytes(data)
        (path.parent / "tex ture.png").write_bytes(TEXTURE)
        gl["buffers"][0]["uri"] = f"{path.stem}.bin"
        gl["images"][0]["uri"] = "tex%20ture.png"
        path.write_text(json.dumps(gl))
    return path


def load(path):
    """``(json, buffers)`` of a .glb or .gltf, decoded here without aobake."""
    path = Path(path)
    data = path.read_bytes()
    if data[:4] == b"glTF":
        (n,) = struct.unpack_from("<I", data, 12)
        gl = json.loads(data[20 : 20 + n])
        (m,) = struct.unpack_from("<I", data, 20 + n)
        blobs = [data[28 + n : 28 + n + m]]
        blobs += [_uri(path, b["uri"]) for b in gl["buffers"][1:]]
    else:
        gl = json.loads(data)
        blobs = [_uri(path, b["uri"]) for b in gl["buffers"]]
    return gl, blobs


def _uri(path: Path, uri: str) -> bytes:
    from urllib.parse import unquote

    if uri.startswith("data:"):
        return base64.b64decode(uri.split(",", 1)[1])
    return (path.parent / unquote(uri)).read_bytes()


def accessor(gl, blobs, index):
    """An accessor's values (count, width) in its stored type (dense, tightly packed or strided)."""
    a = gl["accessors"][index]
    view = gl["bufferViews"][a["bufferView"]]
    dtype = np.dtype("<" + COMPONENTS[a["componentType"]])
    width = WIDTHS[a["type"]]
    stride = view.get("byteStride", dtype.itemsize * width)
    start = view.get("byteOffset", 0) + a.get("byteOffset", 0)
    rows = [
        np.frombuffer(blobs[view["buffer"]], dtype, width, start + i * stride)
        for i in range(a["count"])
    ]
    return np.array(rows).reshape(a["count"], width)


def image_bytes(path, gl, blobs, index=0) -> bytes:
    image = gl["images"][index]
    if "uri" in image:
        return _uri(Path(path), image["uri"])
    view = gl["bufferViews"][image["bufferView"]]
    start = view.get("byteOffset", 0)
    return blobs[view["buffer"]][start : start + view["byteLength"]]
