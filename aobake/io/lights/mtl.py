"""OBJ/MTL: ``Kd`` as albedo and ``Ke`` as emission, per material and so per face
(``mtllib`` and ``usemtl`` of the OBJ); PLY: vertex (else face) colours as albedo. Neither format
has lights. Imports numpy only.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...errors import InputError
from ...shading import DEFAULT_ALBEDO
from ..color import srgb_to_linear
from ..common import decode_text
from ..ply import COLOR_NAMES, vertex_colors
from .reading import Reading, check_colour


def read_obj(reading: Reading) -> None:
    """Per-face Kd and Ke from the MTL files an OBJ names, by its ``usemtl`` lines."""
    path = reading.path
    text = decode_text(path, path.read_bytes(), "OBJ")
    libraries: list[str] = []
    current: str | None = None
    face_material: list[str | None] = []
    for line in text.splitlines():
        tokens = line.split()
        if not tokens:
            continue
        if tokens[0] == "f":
            face_material.append(current)
        elif tokens[0] == "usemtl":
            current = " ".join(tokens[1:]) or None
        elif tokens[0] == "mtllib":
            libraries += tokens[1:]
    if not libraries and all(m is None for m in face_material):
        return
    materials: dict[str, dict] = {}
    for name in libraries:
        mtl = path.parent / name
        if not mtl.is_file():
            reading.note(f"{path.name}: mtllib {name} not found; its materials get the default albedo {DEFAULT_ALBEDO}")
            continue
        for key, value in read_mtl(mtl).items():
            materials.setdefault(key, value)
    counts = np.concatenate([p.face_vertex_counts for p in reading.surface.parts])
    if len(counts) != len(face_material):
        raise InputError(path, f"has {len(face_material)} f lines but {len(counts)} faces were read")
    albedo = np.full((len(counts), 3), DEFAULT_ALBEDO)
    emission = np.zeros((len(counts), 3))
    for name in dict.fromkeys(m for m in face_material if m is not None):
        rows = np.array([m == name for m in face_material])
        entry = materials.get(name)
        if entry is None:
            reading.note(f"{path.name}: material {name!r} is in no MTL file; default albedo {DEFAULT_ALBEDO}")
            continue
        if "Kd" in entry:
            albedo[rows] = check_colour(entry["Kd"], reading, f"material {name!r}", "Kd", albedo=True)
            reading.albedo_source("MTL Kd")
        if "Ke" in entry:
            emission[rows] = check_colour(entry["Ke"], reading, f"material {name!r}", "Ke", albedo=False)
            if (emission[rows] > 0).any():
                reading.emission_source("MTL Ke")
    owner = np.repeat(np.arange(len(counts)), np.maximum(counts - 2, 0))
    if len(owner) != reading.surface.n_faces:
        raise InputError(path, f"its polygons give {len(owner)} triangles but {reading.surface.n_faces} were read")
    reading.face_albedo[:] = albedo[owner]
    reading.face_emission[:] = emission[owner]


def read_mtl(path: Path) -> dict[str, dict]:
    """``{material: {"Kd": (3,), "Ke": (3,)}}`` of an MTL file (other statements are
    not used; ``Kd spectral`` and ``Kd xyz`` are errors)."""
    text = decode_text(path, path.read_bytes(), "MTL")
    out: dict[str, dict] = {}
    current: dict | None = None
    for number, line in enumerate(text.splitlines(), 1):
        tokens = line.split("#", 1)[0].split()
        if not tokens:
            continue
        if tokens[0] == "newmtl":
            current = out.setdefault(" ".join(tokens[1:]), {})
        elif tokens[0] in ("Kd", "Ke") and current is not None:
            args = tokens[1:]
            try:
                values = [float(t) for t in args]
            except ValueError:
                values = []
            if len(values) == 1:
                values *= 3  # "Kd r": g and b default to r
            if len(values) != 3:
                raise InputError(path, f"line {number}: {tokens[0]} needs 1 or 3 numbers (spectral and xyz are not read), got {' '.join(args)[:40]!r}")
            current[tokens[0]] = values
    return out


def read_ply_colours(reading: Reading) -> None:
    """PLY colours ``red green blue`` as albedo, of the vertices (else of the faces):
    integer colours are sRGB-encoded (decoded to linear), float colours taken as linear."""
    kept = reading.surface.metadata.get("ply")
    if kept is None:
        return
    found = vertex_colors(kept)
    if found is not None:
        linear = _linear_colours(reading, *found, "vertex")
        if len(linear) != reading.surface.n_vertices:
            raise ValueError(
                f"{reading.path.name}: {len(linear)} PLY colours for {reading.surface.n_vertices} vertices "
                "(read the shading before welding)"
            )
        reading.face_albedo[:] = linear[reading.surface.faces].mean(axis=1)
        reading.vertex_albedo[:] = linear
        return
    face = kept.data.elements.get("face")
    columns = {} if face is None else face.properties
    if not all(isinstance(columns.get(c), np.ndarray) for c in COLOR_NAMES[:3]):
        return
    dtype = dict((n, t) for n, t, _ in kept.types["face"])["red"]
    linear = _linear_colours(reading, np.column_stack([columns[c] for c in COLOR_NAMES[:3]]), dtype, "face")
    counts = np.concatenate([p.face_vertex_counts for p in reading.surface.parts])
    owner = np.repeat(np.arange(len(counts)), np.maximum(counts - 2, 0))
    if len(counts) != len(linear) or len(owner) != reading.surface.n_faces:
        raise InputError(reading.path, f"has {len(linear)} face colours for {len(counts)} faces")
    reading.face_albedo[:] = linear[owner]


def _linear_colours(reading: Reading, values, dtype, element: str) -> np.ndarray:
    values = np.asarray(values[:, :3], dtype=np.float64)
    if np.dtype(dtype).kind in "iu":
        top = float(np.iinfo(np.dtype(dtype)).max)
        reading.albedo_source(f"PLY {element} colours (sRGB-encoded integers)")
        return srgb_to_linear(check_colour(values, reading, element, "colour", albedo=False) / top)
    reading.albedo_source(f"PLY {element} colours (float, linear)")
    return check_colour(values, reading, element, "colour", albedo=True)
