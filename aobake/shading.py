"""What a scene holds besides geometry: lights, surface albedo and emission.

The readers (:mod:`aobake.io.lights`) fill a :class:`Shading` from a file's own light and
material data (UsdLux, KHR_lights_punctual, MTL, PLY colours) and from ``--light``; the
light transport (:mod:`aobake.methods.embree.light`) and the planner read it. Every
quantity is linear RGB in the scene's own light units, float64, world space (the
:class:`aobake.mesh.Surface`'s coordinates). Imports numpy only.

Conventions, one per light kind (what ``Light.value`` means):

==========  =============================================================================
kind        ``value`` and the fields used
==========  =============================================================================
distant     irradiance E_perp on a surface facing the light; ``direction`` (unit, from the
            surface towards the light); ``angle`` the apex angle of the cone of
            directions it covers (radians, 0 = one direction)
point       radiant intensity I: E = I cos(theta) / d^2; ``position``
spot        as point, on the axis; ``direction`` (unit, the way the light shines),
            ``cone_inner`` / ``cone_outer`` (half-angles, radians): full intensity inside
            the inner cone, none outside the outer, glTF's falloff between them
sphere      radiance L of a sphere of ``radius`` at ``position`` (emits outward)
rect        radiance L of a one-sided rectangle centred at ``position`` with half-edge
            vectors ``u`` and ``v``; it emits on the side of ``normal`` = unit(u x v)
disk        radiance L of a one-sided disk of ``radius`` at ``position`` facing ``normal``
dome        radiance L of a uniform environment at infinity (E = pi L (1 - A) when open)
==========  =============================================================================

Every light has a ``name`` (USD prim path, glTF node name or ``--light 2``), ``shadow``
(False: it casts no shadow rays, it lights every receiver that faces it) and ``range``
(glTF's cutoff distance; inf = none).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ._types import FloatArray

#: The kinds a :class:`Light` may have, in the order ``aobake plan`` lists them.
LIGHT_KINDS = ("distant", "point", "spot", "sphere", "rect", "disk", "dome")

#: Kinds with an area: their direct light is estimated by sampling the area.
AREA_KINDS = ("sphere", "rect", "disk")

#: Albedo a surface gets when the file gives it none (a mid-grey card's 18%).
DEFAULT_ALBEDO = 0.18

_ZERO3 = (0.0, 0.0, 0.0)


def _vec3(value, what: str, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"light {name}: {what} must be 3 finite numbers, got {value!r}")
    return arr


def _unit(value, what: str, name: str) -> np.ndarray:
    arr = _vec3(value, what, name)
    length = float(np.linalg.norm(arr))
    if not length > 0.0:
        raise ValueError(f"light {name}: {what} has zero length")
    return arr / length


@dataclass(frozen=True)
class Light:
    """One light, in world space; see the module docstring for what each kind uses.

    Construct with :meth:`make`, which checks and normalises the fields (``ValueError``
    with a one-line reason naming the light on bad data); readers turn that into an
    ``InputError`` naming the file.
    """

    kind: str
    name: str
    value: FloatArray  # (3,) linear RGB, the quantity of the table above
    position: FloatArray = field(default_factory=lambda: np.zeros(3))
    direction: FloatArray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    u: FloatArray = field(default_factory=lambda: np.zeros(3))
    v: FloatArray = field(default_factory=lambda: np.zeros(3))
    normal: FloatArray = field(default_factory=lambda: np.array([0.0, 0.0, -1.0]))
    radius: float = 0.0
    angle: float = 0.0
    cone_inner: float = 0.0
    cone_outer: float = math.pi
    shadow: bool = True
    range: float = math.inf

    @classmethod
    def make(
        cls,
        kind: str,
        name: str,
        value,
        *,
        position=_ZERO3,
        direction=(0.0, 0.0, 1.0),
        u=_ZERO3,
        v=_ZERO3,
        normal=None,
        radius: float = 0.0,
        angle: float = 0.0,
        cone_inner: float = 0.0,
        cone_outer: float = math.pi,
        shadow: bool = True,
        range: float = math.inf,  # noqa: A002 - glTF's name for it
    ) -> Light:
        """A checked light: finite, non-negative ``value``; a positive area for area kinds;
        unit directions; angles in range. Raises ``ValueError`` naming ``name``."""
        if kind not in LIGHT_KINDS:
            raise ValueError(f"light {name}: unknown kind {kind!r} (known: {', '.join(LIGHT_KINDS)})")
        value = _vec3(value, "value", name)
        if np.any(value < 0):
            raise ValueError(f"light {name}: negative colour or intensity {tuple(value)}")
        position = _vec3(position, "position", name)
        direction = _unit(direction, "direction", name) if kind in ("distant", "spot") else _vec3(direction, "direction", name)
        u = _vec3(u, "u", name)
        v = _vec3(v, "v", name)
        for what, x in (("radius", radius), ("angle", angle), ("cone_inner", cone_inner), ("cone_outer", cone_outer)):
            if not math.isfinite(x) or x < 0:
                raise ValueError(f"light {name}: {what} must be a finite number >= 0, got {x}")
        if not (range > 0) or math.isnan(range):
            raise ValueError(f"light {name}: range must be > 0, got {range}")
        if kind == "rect":
            cross = np.cross(u, v)
            if not np.linalg.norm(cross) > 0:
                raise ValueError(f"light {name}: a rectangle light of zero area")
            normal = cross / np.linalg.norm(cross)
        elif kind == "disk":
            if not radius > 0:
                raise ValueError(f"light {name}: a disk light of zero area (radius {radius})")
            normal = _unit(normal if normal is not None else (0.0, 0.0, -1.0), "normal", name)
        elif kind == "sphere":
            if not radius > 0:
                raise ValueError(f"light {name}: a sphere light of zero area (radius {radius})")
        if normal is None:
            normal = (0.0, 0.0, -1.0)
        normal = _vec3(normal, "normal", name)
        if angle >= math.pi:
            raise ValueError(f"light {name}: angle must be below pi, got {angle}")
        if kind == "spot" and not cone_inner <= cone_outer <= math.pi:
            raise ValueError(f"light {name}: cone angles need 0 <= inner <= outer <= pi, got {cone_inner}, {cone_outer}")
        return cls(
            kind, name, value, position, direction, u, v, normal,
            float(radius), float(angle), float(cone_inner), float(cone_outer), bool(shadow), float(range),
        )

    @property
    def area(self) -> float:
        """Emitting area (world units squared) of an area light; 0 for the others."""
        if self.kind == "rect":
            return 4.0 * float(np.linalg.norm(np.cross(self.u, self.v)))
        if self.kind == "disk":
            return math.pi * self.radius**2
        if self.kind == "sphere":
            return 4.0 * math.pi * self.radius**2
        return 0.0

    @property
    def is_black(self) -> bool:
        """True when the light adds nothing (all of ``value`` is zero)."""
        return not bool(np.any(self.value > 0))


@dataclass(frozen=True)
class Shading:
    """Lights and surface properties of a surface's vertices and faces.

    Attributes
    ----------
    lights : tuple of Light
    face_albedo : (m, 3) float64 in [0, 1]
        Diffuse reflectance of each triangle of ``surface.faces`` (what bounce rays that
        hit it reflect).
    face_emission : (m, 3) float64 >= 0
        Emitted radiance of each triangle (emissive meshes are area lights that still
        occlude).
    vertex_albedo : (n, 3) float64 in [0, 1]
        Albedo at each vertex, for the lit colour ``--color`` writes (a per-vertex
        source as read; a per-face source: the mean over the vertex's faces).
    vertex_emission : (n, 3) float64 >= 0
        Emission at each vertex, added to the lit colour (never to its irradiance).
    sources : dict
        Where each quantity came from, for ``aobake plan`` and the output's custom data,
        e.g. ``{"albedo": "UsdPreviewSurface diffuseColor", "emission": "none"}``.
    notes : tuple of str
        What the reader skipped or approximated (a textured dome read as its average),
        shown as warnings.
    """

    lights: tuple[Light, ...]
    face_albedo: FloatArray
    face_emission: FloatArray
    vertex_albedo: FloatArray
    vertex_emission: FloatArray
    sources: dict = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    @property
    def has_emitters(self) -> bool:
        """True when some triangle emits."""
        return bool(np.any(self.face_emission > 0))

    @property
    def has_light(self) -> bool:
        """True when some light or emitting triangle adds light."""
        return self.has_emitters or any(not light.is_black for light in self.lights)

    @property
    def reflects(self) -> bool:
        """True when some triangle has albedo above zero (bounces can add light)."""
        return bool(np.any(self.face_albedo > 0))


def default_shading(n_vertices: int, n_faces: int, lights=()) -> Shading:
    """Every surface 0.18 grey, nothing emitting, ``lights`` as given."""
    return Shading(
        tuple(lights),
        np.full((n_faces, 3), DEFAULT_ALBEDO),
        np.zeros((n_faces, 3)),
        np.full((n_vertices, 3), DEFAULT_ALBEDO),
        np.zeros((n_vertices, 3)),
        {"albedo": f"default {DEFAULT_ALBEDO}", "emission": "none"},
    )


def vertex_means(faces: np.ndarray, face_values: FloatArray, n_vertices: int) -> FloatArray:
    """(n, k): each vertex's mean of its faces' rows (zero for a vertex on no face)."""
    faces = np.asarray(faces, dtype=np.int64)
    corners = faces.ravel()
    count = np.bincount(corners, minlength=n_vertices).astype(np.float64)
    rows = np.repeat(np.asarray(face_values, dtype=np.float64), faces.shape[1], axis=0)
    total = np.stack([np.bincount(corners, weights=rows[:, c], minlength=n_vertices) for c in range(rows.shape[1])], axis=1)
    return total / np.maximum(count, 1.0)[:, None]


@dataclass(frozen=True)
class LightStats:
    """What one light cost and skipped (``name`` "emitters" for the emitting triangles).

    Attributes
    ----------
    name : str
    behind, cone, range, no_normal : int
        Receivers (vertices) it cannot reach, by reason: behind the tangent plane (or
        on the back of a one-sided light), outside a spot's outer cone, beyond
        ``range``, vertex without a normal. They cost no ray.
    shadow_rays : int
        Shadow rays it cast from the vertices (direct light; a dome's are the paths'
        first rays, counted in ``n_bounce_rays``).
    """

    name: str
    behind: int = 0
    cone: int = 0
    range: int = 0
    no_normal: int = 0
    shadow_rays: int = 0

    @property
    def skipped(self) -> int:
        return self.behind + self.cone + self.range + self.no_normal


@dataclass(frozen=True)
class LightResult:
    """What a method's light transport returns (``aobake.methods.run_light``: the reference's
    ``irradiance``, the disk method's transfer): per-vertex irradiance on the side the
    normal points to.

    Attributes
    ----------
    direct, indirect : (n, 3) float64 >= 0
        Linear RGB irradiance in the scene's light units: straight from the lights,
        emitters and dome; and after 1..K bounces.
    error : (n, 3) float64
        95% half-width of the estimate of direct + indirect (per channel); zero for the
        disk method, which draws no samples (its bias is measured, docs/bunnell-light.md).
    n_shadow_rays : int
        Shadow rays cast from the vertices (direct light).
    n_bounce_rays : int
        Path rays (their first rays included: they also see the dome) and the shadow
        rays cast from the paths' hit points.
    lights : tuple of LightStats
        One per ``shading.lights``, then one for the emitting triangles.
    samples : (n,) int64
        Samples per area light taken at each vertex (fewer than ``n_samples`` where
        ``tolerance`` stopped it early).
    seconds : float
    contacts : int
    negative : int
        Vertices whose light would have gone negative and was set to 0 (the disk
        method's shadow subtraction of bounced light; always 0 for the reference).
    clipped : float
        What setting them to 0 added: the negative parts' magnitude summed over those
        vertices and the three channels (scene units; compare ``irradiance.sum()``).
    """

    direct: np.ndarray
    indirect: np.ndarray
    error: np.ndarray
    n_shadow_rays: int
    n_bounce_rays: int
    lights: tuple
    samples: np.ndarray
    seconds: float
    contacts: int
    negative: int = 0
    clipped: float = 0.0

    @property
    def irradiance(self) -> np.ndarray:
        return self.direct + self.indirect


def check_shading(surface, shading: Shading) -> None:
    """ValueError unless ``shading``'s arrays fit ``surface`` and are finite, albedo in
    [0, 1] and emission >= 0 (a reader's bug, not a user's file: readers check those)."""
    m, n = surface.n_faces, surface.n_vertices
    for name, rows in (("face_albedo", m), ("face_emission", m), ("vertex_albedo", n), ("vertex_emission", n)):
        arr = np.asarray(getattr(shading, name))
        if arr.shape != (rows, 3):
            raise ValueError(f"shading.{name} has shape {arr.shape}, the surface needs ({rows}, 3)")
        if not np.isfinite(arr).all() or arr.min(initial=0.0) < 0:
            raise ValueError(f"shading.{name} has negative or non-finite values")
    if np.asarray(shading.face_albedo).max(initial=0.0) > 1:
        raise ValueError("shading.face_albedo above 1 would add energy at every bounce")
