"""What every light reader fills: a :class:`Reading` (lights, per-triangle and
per-vertex albedo and emission, sources, notes) turned into a
:class:`aobake.shading.Shading`, and the checks every colour passes.

Imports numpy and aobake's ``errors``, ``mesh`` and ``shading`` only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import InputError
from ...mesh import Surface, fan_triangulate, reverse_polygons
from ...shading import DEFAULT_ALBEDO, Light, Shading, vertex_means


@dataclass
class Reading:
    """A shading being read: triangle values start at the defaults (0.18 grey, no
    emission); vertex rows left NaN become the mean of their triangles."""

    surface: Surface
    path: Path
    lights: list[Light] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    albedo_from: list[str] = field(default_factory=list)
    emission_from: list[str] = field(default_factory=list)
    lights_from: str = "none"

    def __post_init__(self) -> None:
        n, m = self.surface.n_vertices, self.surface.n_faces
        self.face_albedo = np.full((m, 3), DEFAULT_ALBEDO)
        self.face_emission = np.zeros((m, 3))
        self.vertex_albedo = np.full((n, 3), np.nan)
        self.vertex_emission = np.full((n, 3), np.nan)

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)

    def albedo_source(self, label: str) -> None:
        if label not in self.albedo_from:
            self.albedo_from.append(label)

    def emission_source(self, label: str) -> None:
        if label not in self.emission_from:
            self.emission_from.append(label)

    def set_part(self, which: str, part, face_values, vertex_values=None) -> None:
        """Store ``which`` ("albedo" or "emission") for one part: ``face_values``
        (triangles of the part, 3) and optionally ``vertex_values`` (its vertices, 3)."""
        faces = getattr(self, f"face_{which}")
        faces[part.face_start : part.face_stop] = face_values
        if vertex_values is not None:
            getattr(self, f"vertex_{which}")[part.vertex_start : part.vertex_stop] = vertex_values

    def shading(self) -> Shading:
        faces = self.surface.faces
        n = self.surface.n_vertices
        on_face = np.zeros(n, dtype=bool)
        on_face[faces.reshape(-1)] = True
        out = {}
        for which, fill in (("albedo", DEFAULT_ALBEDO), ("emission", 0.0)):
            if not getattr(self, f"{which}_from"):  # nothing read: every vertex has the default
                out[which] = np.full((n, 3), fill)
                continue
            vertex = getattr(self, f"vertex_{which}").copy()
            missing = np.isnan(vertex).any(axis=1)
            if missing.any():
                means = vertex_means(faces, getattr(self, f"face_{which}"), n)
                means[~on_face] = fill
                vertex[missing] = means[missing]
            out[which] = vertex
        albedo = ", ".join(self.albedo_from) or f"default {DEFAULT_ALBEDO}"
        if self.albedo_from and bool((self.face_albedo == DEFAULT_ALBEDO).all(axis=1).any()):
            if f"default {DEFAULT_ALBEDO}" not in albedo:
                albedo += f", default {DEFAULT_ALBEDO} elsewhere"
        sources = {
            "albedo": albedo,
            "emission": ", ".join(self.emission_from) or "none",
            "lights": self.lights_from,
        }
        return Shading(
            tuple(self.lights),
            self.face_albedo,
            self.face_emission,
            out["albedo"],
            out["emission"],
            sources,
            tuple(self.notes),
        )


def check_colour(values, reading: Reading, where: str, what: str, *, albedo: bool) -> np.ndarray:
    """``values`` (k, 3) or (3,) as float64 after the checks: NaN/inf and negative values
    are an :class:`InputError` naming ``where``; albedo above 1 is clamped (a note)."""
    arr = np.asarray(values, dtype=np.float64)
    if not np.isfinite(arr).all():
        raise InputError(reading.path, f"{where}: {what} is not finite (NaN or inf)")
    if (arr < 0).any():
        worst = float(arr.min())
        raise InputError(reading.path, f"{where}: negative {what} ({worst:g})")
    if albedo and (arr > 1).any():
        reading.note(f"{where}: {what} above 1 ({float(arr.max()):g}) clamped to 1 (a surface reflects at most what it receives)")
        arr = np.minimum(arr, 1.0)
    return arr


def triangle_corners(counts, indices, local_faces, holes=(), *, path=None, where: str = "") -> np.ndarray:
    """(m, 3) positions in the flat polygon corner list of each triangle of a part.

    The readers fan polygons (holes dropped) from their first corner, after reversing
    the corner order of left-handed meshes; both orders are tried and the one whose
    triangles are ``local_faces`` (vertex indices local to the part) is kept.
    """
    counts = np.asarray(counts, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    keep = np.ones(len(counts), dtype=bool)
    holes = np.asarray(holes, dtype=np.int64).reshape(-1)
    keep[holes[(holes >= 0) & (holes < len(counts))]] = False
    ids = np.arange(len(indices), dtype=np.int64)
    want = np.sort(np.asarray(local_faces, dtype=np.int64), axis=1)
    for order in (ids, reverse_polygons(counts, ids)):
        tri = fan_triangulate(counts[keep], order[np.repeat(keep, counts)])
        if tri.shape == want.shape and np.array_equal(np.sort(indices[tri], axis=1), want):
            return tri
    raise InputError(path, f"{where}: its polygons do not give the triangles read for the bake")
