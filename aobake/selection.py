"""Who casts and who receives: ``--occluders`` and ``--receivers`` globs over the parts of
a surface (USD prim paths, else glTF node, OBJ object or file names).

Occluders not selected leave the traced scene (their triangles are dropped; their
vertices stay, so vertex indices and rays are those of the whole mesh) but are still
written. Receivers not selected keep the input's own ``ao`` (:func:`kept_ao`).
Imports numpy only.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .errors import InputError
from .mesh import Surface

#: Part names a "matches nothing" message lists at most.
_NAMES_SHOWN = 5


def part_name(part) -> str:
    """What a pattern is matched against: the USD prim path, else the part's name."""
    return part.prim_path or part.name


def match_parts(surface: Surface, patterns: Sequence[str], option: str) -> np.ndarray:
    """(parts,) bool: which parts some pattern matches (:func:`fnmatch.fnmatchcase`;
    ``*`` also crosses ``/``). Every pattern must match a part.

    Raises
    ------
    InputError
        ``--receivers '/World/nope*' matches no part; parts: /World/a, /World/b, ...``
    """
    names = [part_name(part) for part in surface.parts]
    selected = np.zeros(len(names), dtype=bool)
    for pattern in patterns:
        hit = np.array([fnmatch.fnmatchcase(name, pattern) for name in names], dtype=bool)
        if not hit.any():
            shown = ", ".join(names[:_NAMES_SHOWN]) + (", ..." if len(names) > _NAMES_SHOWN else "")
            raise InputError(surface.source, f"{option} {pattern!r} matches no part; parts: {shown}")
        selected |= hit
    return selected


@dataclass(frozen=True)
class Selection:
    """Which parts cast (``occluders``) and receive (``receivers``), one flag per part,
    and the patterns that chose them (``provenance``, recorded in the outputs)."""

    occluders: np.ndarray
    receivers: np.ndarray
    provenance: dict

    @classmethod
    def of(cls, surface: Surface, receivers: Sequence[str] = (), occluders: Sequence[str] = ()):
        """The selection the patterns make (no patterns: every part), or None when both
        are empty (nothing to select: the plain bake)."""
        if not receivers and not occluders:
            return None
        every = np.ones(len(surface.parts), dtype=bool)
        provenance = {key: " ".join(patterns) for key, patterns in
                      (("receivers", receivers), ("occluders", occluders)) if patterns}  # fmt: skip
        return cls(
            occluders=match_parts(surface, occluders, "--occluders") if occluders else every,
            receivers=match_parts(surface, receivers, "--receivers") if receivers else every,
            provenance=provenance,
        )

    def kept_faces(self, surface: Surface) -> np.ndarray:
        """(m,) bool: the triangles of the occluders."""
        keep = np.zeros(surface.n_faces, dtype=bool)
        for part, casts in zip(surface.parts, self.occluders, strict=True):
            keep[part.face_start : part.face_stop] = casts
        return keep

    def scene(self, surface: Surface) -> Surface:
        """``surface`` with only the occluders' triangles (all vertices kept, in order)."""
        if self.occluders.all():
            return surface
        keep = self.kept_faces(surface)
        if not keep.any():
            raise InputError(surface.source, "--occluders selects parts without triangles; nothing casts")
        return replace(surface, faces=surface.faces[keep])

    def receiving(self, surface: Surface) -> np.ndarray:
        """(n,) bool: the vertices of receiving parts."""
        out = np.zeros(surface.n_vertices, dtype=bool)
        for part, receives in zip(surface.parts, self.receivers, strict=True):
            out[part.vertex_start : part.vertex_stop] = receives
        return out


def unselected_values(name: str, surface: Surface, values: np.ndarray) -> np.ndarray:
    """What an extra attribute (baked ``values``, any rows) holds at vertices not baked,
    for all n vertices: ``bentNormal`` the vertex normal, anything else 0."""
    if name == "bentNormal":
        return np.asarray(surface.normals, dtype=np.float64)
    return np.zeros((surface.n_vertices, *np.shape(values)[1:]))


def kept_ao(surface: Surface) -> np.ndarray:
    """(n,) float64: the ``ao`` the input already holds, per part, else 1.0 (open).

    Read from a PLY input's vertex ``ao``, a USD input's ``primvars:ao`` (one value per
    point, at the time the mesh was read) or a glTF input's ``_AO``. A part whose stored
    values are missing, of another length, non-finite or outside [0, 1] gets 1.0.
    """
    out = np.ones(surface.n_vertices, dtype=np.float64)
    for part, values in _stored_ao(surface):
        values = None if values is None else np.asarray(values, dtype=np.float64).reshape(-1)
        if values is None or values.shape != (part.n_vertices,):
            continue
        if np.isfinite(values).all() and values.min(initial=1.0) >= 0.0 and values.max(initial=0.0) <= 1.0:
            out[part.vertex_start : part.vertex_stop] = values
    return out


def _stored_ao(surface: Surface):
    """``(part, values or None)`` for every part that may hold stored ``ao``."""
    meta = surface.metadata
    if meta.get("ply") is not None:
        column = meta["ply"].data.elements["vertex"].properties.get("ao")
        if isinstance(column, np.ndarray) and len(surface.parts) == 1:
            yield surface.parts[0], column
    elif meta.get("format") == "USD" and meta.get("path"):
        from pxr import Sdf, Usd, UsdGeom

        from .io.usd import _open_fresh

        time = meta.get("time")
        code = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
        # the stage the mesh reader opened (within a bake), else fresh from disk: never a
        # stale layer the registry still holds for the path
        stage = _open_fresh(Path(meta["path"]), Sdf, Usd)
        if stage is None:
            return
        for part in surface.parts:
            prim = stage.GetPrimAtPath(part.prim_path) if part.prim_path else None
            primvar = UsdGeom.PrimvarsAPI(prim).GetPrimvar("ao") if prim else None
            if primvar and primvar.HasAuthoredValue():
                yield part, primvar.ComputeFlattened(code)
        del stage
    elif meta.get("gltf_path"):
        from .io import gltf

        doc = gltf.read_document(meta["gltf_path"])
        for slot, part in gltf.match_parts(doc, surface, warn=False):
            attributes = doc.json["meshes"][slot.mesh]["primitives"][slot.primitive]["attributes"]
            if "_AO" in attributes:
                a = attributes["_AO"]
                normalized = doc.json["accessors"][a].get("normalized", False)
                yield part, gltf.as_float(gltf.accessor_values(doc, a), normalized)[:, 0]
