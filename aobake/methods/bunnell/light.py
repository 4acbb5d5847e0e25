"""Bunnell's light: direct and bounced irradiance through the disk-to-disk transfer
(docs/bunnell-light.md).

Point, spot and sharp distant lights are exact, one Embree shadow ray per light and
vertex (the reference's kernels). Area lights and emitting triangles are tessellated into
emitting disks, and the vertices' disks reflect; their light reaches the vertices by the
transfer, shadowed as the GPU Gems 2 chapter does: one pass distributes it unshadowed,
each following pass subtracts what the vertex disks block, weighted by the light that
reaches their far side in the pass before. A dome is pi L (1 - A), A from the disk AO.
Numpy-facing; the sums are :func:`_gather`.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, fields, replace

import numpy as np

from ...checks import mesh_threads, numba_threads
from ...constants import (
    BLOCK_RAYS,
    EPS32,
    INFINITE_DISTANCE,
    LIGHT_DISKS,
    NEAR_OFFSET_REL,
    RAY_OFFSET_ULPS,
)
from ...contacts import contact_origins, ray_offsets
from ...errors import InputError, NumericalError
from ...ground import Ground
from ...kernels import hierarchy as _h
from ...kernels import lights as _kl
from ...kernels import lightshadow as _kls
from ...kernels import rays as _k
from ...kernels import topology as _topo
from ...kernels import warps as _warps
from ...mesh import Surface
from ...progress import NullProgress, Progress
from ...shading import AREA_KINDS, LightResult, LightStats, Shading, check_shading
from ...tracing import tracer_for
from .elements import DiskElements, build_elements
from .lighttree import (
    AIMED_EDGE,
    AIMED_THETA,
    LIGHT_THETA,
    DiskTree,
    Receivers,
    aimed_shadow_tree,
    tree_gather,
)
from .options import BunnellOptions
from .passes import SHARE_COS
from .transfer import transfer

#: Most vertices lit: memory, about 2.2 kB a vertex through the trees (a 699,889-vertex
#: scene under a rect light peaked at 1.5 GB), so about 11 GB here.
MAX_VERTICES = 5_000_000

#: Most vertices the brute-force passes (``theta=None``, the tests' reference) take: every
#: pass costs O(n^2) (20,000 vertices: about a second per pass on two cores).
BRUTE_MAX_VERTICES = 20_000

#: Patches each light (and the emitting triangles together) is cut into for the aimed
#: shadow pass: every receiver, occluder and patch is a term.
LIGHT_PATCHES = 16


#: Shadow passes after the pass that distributes the light (the published scheme: two).
SHADOW_PASSES = 2


@dataclass(frozen=True)
class EmitterDisks:
    """Emitting disks in the elements' normalised frame: area lights and emitting
    triangles tessellated (one-sided: each emits on its normal's side).

    Attributes
    ----------
    centres, normals : (k, 3) float64
    areas : (k,) float64
    radiance : (k, 3) float64
    group : (k,) int64
        The light each disk belongs to: 0, 1... in the order of the lights cut, the
        emitting triangles last (one group).
    """

    centres: np.ndarray
    normals: np.ndarray
    areas: np.ndarray
    radiance: np.ndarray
    group: np.ndarray

    @property
    def n_groups(self) -> int:
        return int(self.group.max()) + 1 if self.group.size else 0

    @property
    def size(self) -> int:
        return int(self.areas.shape[0])


def run_light(
    surface: Surface,
    shading: Shading,
    options: BunnellOptions,
    progress: Progress | None = None,
    *,
    indirect: bool = True,
    ground: Ground | None = None,
) -> LightResult:
    """The method interface (:func:`aobake.methods.run_light`): :func:`disk_light` with
    ``options`` (its ``bounces``; ``indirect=False``: direct light only). A vertex whose
    shadowed light went negative is set to 0 and counted (a warning, and ``negative``)."""
    result = disk_light(surface, shading, options, bounces=options.bounces if indirect else 0, progress=progress, ground=ground)
    if result.negative:
        total = float(result.irradiance.sum())
        share = result.clipped / total if total > 0 else 0.0
        warnings.warn(
            f"{surface.source}: the disk method's shadow passes took {result.negative:,} of {surface.n_vertices:,} "
            f"vertices' light below zero; set to 0, which added {share:.2%} to the irradiance "
            "(--method embree traces it)",
            stacklevel=2,
        )
    return result


def disk_light(
    surface: Surface,
    shading: Shading,
    options: BunnellOptions | None = None,
    *,
    bounces: int | None = None,
    shadow_passes: int = SHADOW_PASSES,
    light_disks: int = LIGHT_DISKS,
    aimed: bool = True,
    faces_occlude: bool = True,
    theta: float | None = LIGHT_THETA,
    aimed_theta: float = AIMED_THETA,
    aimed_edge: float = AIMED_EDGE,
    share: bool = True,
    near: float | None = None,
    progress: Progress | None = None,
    ground: Ground | None = None,
) -> LightResult:
    """Per-vertex irradiance (direct and indirect, RGB) of ``surface`` lit by ``shading``.

    Parameters
    ----------
    surface : Surface
    shading : Shading
    options : BunnellOptions, optional
        ``bounces`` (overridden by ``bounces``), ``max_distance`` (geometry farther from a
        receiver neither occludes nor reflects: the shadow rays, the dome's AO, the shadow
        passes and the bounce; the lights themselves are not capped), ``threads`` and the
        AO settings a dome uses.
    bounces : int, optional
    shadow_passes : int
        Passes after the distributing one (0 = unshadowed transfer).
    light_disks : int
        Disks each area light (and the emitting triangles together) is cut into.
    aimed : bool
        Shadow the emitted light with :func:`_aimed` (a disk blocks a light only along
        the line from the receiver through it to the light); False: as the bounced
        light, the published scheme (each disk blocks the light falling on its far side
        from every direction alike).
    faces_occlude : bool
        The triangles occlude (False: the vertex disks, as published).
    theta : float or None
        Opening parameter of the cluster trees the bounced light and the shadow passes'
        subtraction go through (``inf``: every cluster opened, the brute-force sums);
        None: the brute-force passes themselves (O(n^2): at most BRUTE_MAX_VERTICES).
    aimed_theta, aimed_edge : float
        Opening parameters of the aimed pass's occluder tree (with ``theta`` not None):
        ``lighttree.aimed_shadow_tree``.
    share : bool
        With ``theta`` not None: the aimed passes that only weight the next one are
        evaluated at one vertex per leaf of the vertex tree and shared with the leaf's
        vertices of like normal (as the AO's later passes); False: at every vertex.
    near : float >= 0, optional
        With ``theta`` not None, at full-resolution receivers: a vertex disk (the bounce)
        or a triangle (the shadow subtraction, ``faces_occlude``) within ``sqrt(near A)``
        counts with the exact form factor of its polygon clipped to the receiver's tangent
        plane instead of as a disk, as the AO's near field; 0: disks only. Default:
        ``options.near`` (``--near``, 4).
    ground : aobake.ground.Ground, optional
        Occludes the shadow rays and the dome; with bounces, it also reflects (albedo
        ``aobake.ground.ALBEDO``) as a grid of ground elements about the surface
        (:func:`ground_grid`).

    Returns
    -------
    LightResult
        ``error`` zeros (nothing is sampled), ``n_bounce_rays`` 0, ``samples`` zeros,
        ``negative``: vertices whose shadowed light went below zero (set to 0).
    """
    t0 = time.perf_counter()
    reflects = ((options or BunnellOptions()).bounces if bounces is None else int(bounces)) > 0  # the ground's grid
    scene = prepare_light(surface, shading, options, shadow_passes=shadow_passes, light_disks=light_disks, aimed=aimed,
                          faces_occlude=faces_occlude, theta=theta, aimed_theta=aimed_theta, aimed_edge=aimed_edge,
                          share=share, near=near, ground=ground, ground_reflects=reflects)  # fmt: skip
    result = scene.light(bounces=bounces, progress=progress)
    return replace(result, seconds=time.perf_counter() - t0)


def prepare_light(
    surface: Surface,
    shading: Shading,
    options: BunnellOptions | None = None,
    *,
    shadow_passes: int = SHADOW_PASSES,
    light_disks: int = LIGHT_DISKS,
    aimed: bool = True,
    faces_occlude: bool = True,
    theta: float | None = LIGHT_THETA,
    aimed_theta: float = AIMED_THETA,
    aimed_edge: float = AIMED_EDGE,
    share: bool = True,
    near: float | None = None,
    ground: Ground | None = None,
    ground_reflects: bool = True,
) -> LitScene:
    """``surface`` and ``shading`` prepared for :meth:`LitScene.light`, which lights it
    with any lights (moved, re-coloured, added) without rebuilding what does not depend
    on them. The parameters are :func:`disk_light`'s; ``disk_light(...)`` equals
    ``prepare_light(...).light()`` (the same code). With a ``ground`` that
    ``ground_reflects`` (what ``disk_light`` asks for when the light bounces), the scene
    carries a grid of ground elements (:func:`ground_grid`) that receive, reflect and
    occlude like the surface; the results are the surface's vertices alone."""
    options = BunnellOptions() if options is None else options
    check_shading(surface, shading)
    n = surface.n_vertices
    if n > MAX_VERTICES:
        raise InputError(
            surface.source,
            f"{n:,} vertices: --method bunnell lights at most {MAX_VERTICES:,} (about 2.2 kB of memory a vertex; "
            "use --method embree, or --effects ao)",
        )
    if theta is None and n > BRUTE_MAX_VERTICES:
        raise ValueError(f"theta=None (brute force) takes at most {BRUTE_MAX_VERTICES:,} vertices, got {n:,}")
    near = float(options.near if near is None else near)
    if not (near >= 0.0 and math.isfinite(near)):
        raise ValueError(f"near must be finite and >= 0, got {near!r}")
    settings = _Settings(shadow_passes, light_disks, aimed, faces_occlude, theta, (aimed_theta, aimed_edge), share, near)
    mesh = surface
    if ground is not None and ground_reflects:
        surface, shading = ground_grid(surface, shading, ground)
    with numba_threads(mesh_threads(options.threads, n)):
        return LitScene(surface, shading, options, settings, ground, mesh=mesh)


@dataclass(frozen=True)
class _Settings:
    """:func:`disk_light`'s scheme parameters, as a prepared scene keeps them."""

    shadow_passes: int
    light_disks: int
    aimed: bool
    faces_occlude: bool
    theta: float | None
    aimed_tree: tuple  # (aimed_theta, aimed_edge)
    share: bool
    near: float


class LitScene:
    """A surface and its shading prepared for the disk method's light
    (:func:`prepare_light`): the disks, the Embree scene and contact-safe origins of the
    shadow rays, the passes' cluster trees, a dome's AO, and the last area lights' shadowed
    light are built once, on first use, and kept; :meth:`light` recomputes only what the
    lights change (the shadow rays of point, spot and distant lights, the area lights'
    passes when those lights changed, the bounces)."""

    def __init__(self, surface: Surface, shading: Shading, options: BunnellOptions, settings: _Settings,
                 ground: Ground | None, mesh: Surface | None = None):  # fmt: skip
        self.surface, self.shading, self.options, self.settings, self.ground = surface, shading, options, settings, ground
        self.mesh = mesh = surface if mesh is None else mesh  # the input; ``surface`` may carry a ground grid after it
        self.keep = mesh.n_vertices
        self.elements = build_elements(surface)
        # --max-distance in the elements' normalised units: farther geometry neither
        # reflects nor occludes, as the reference's capped rays
        self.reach = math.inf if options.max_distance is None else float(options.max_distance) / self.elements.scale
        # the shadow rays trace the input alone (the plane stands for the grid), so the
        # grid's reach does not coarsen the input's float32 frame and ray offsets
        self._rays = _ShadowRays(mesh, options, ground)
        self._grid_rays = _GridRays(self._rays, surface.positions[self.keep :]) if surface is not mesh else None
        self._trees: _Trees | None = None
        self._ao = None  # the dome's occlusion (cosine measure), once a shadowed dome asks
        self._area_key = None  # the area lights (and emitters) of the kept emitted light
        self._area = None  # (their shadowed light at the vertices, the vertices below zero)

    @property
    def n_vertices(self) -> int:
        return self.surface.n_vertices

    def light(self, lights=None, *, bounces: int | None = None, progress: Progress | None = None) -> LightResult:
        """The irradiance under ``lights`` (a sequence of :class:`aobake.shading.Light`,
        or ``--light`` strings such as ``"point:0,2,0:10"``; default: the shading's own),
        with ``bounces`` (default: the options'); the surface's albedo and emission are
        the shading's. Equals :func:`disk_light` with those lights, bit for bit."""
        lights = self.shading.lights if lights is None else _checked_lights(self.surface, lights)
        bounces = self.options.bounces if bounces is None else int(bounces)
        with numba_threads(mesh_threads(self.options.threads, self.n_vertices)):
            return self._light(tuple(lights), bounces, progress or NullProgress())

    def _light(self, lights: tuple, bounces: int, progress: Progress) -> LightResult:
        st, shading, elements = self.settings, self.shading, self.elements
        n = self.n_vertices
        t0 = time.perf_counter()
        progress.start(2 + (1 + st.shadow_passes) * (1 + bounces), "light")
        exact, stats, contacts, rays = _exact_direct(self._rays, lights)
        if self._grid_rays is not None:  # the ground grid's points, against the input
            grid, grid_stats, _, grid_rays = _exact_direct(self._grid_rays, lights)
            exact, rays = np.concatenate([exact, grid]), rays + grid_rays
            stats = tuple(
                LightStats(a.name, *(getattr(a, f.name) + getattr(b, f.name) for f in fields(LightStats)[1:]))
                for a, b in zip(stats, grid_stats, strict=True)
            )
        progress.advance(1)
        direct = exact
        dome = self._dome(lights)
        if dome is not None:
            direct = direct + dome
        progress.advance(1)
        bouncing = bounces > 0 and shading.reflects
        key = _area_key(lights, st.light_disks)
        negative = np.zeros(n, dtype=bool)
        clipped = np.zeros(n)
        if key == self._area_key:  # the same area lights and emitters: their light is kept
            lit, low, clip = self._area
            direct = direct + lit
            negative |= low
            clipped += clip
            progress.advance(1 + st.shadow_passes)
        else:
            emitters = emitter_disks(elements, shading, lights, st.light_disks)
            if emitters.size:
                trees = self._trees_for(True)
                if st.aimed:
                    patches = _merged(emitter_disks(elements, shading, lights, LIGHT_PATCHES), LIGHT_PATCHES)
                    emitting = _emitting_vertices(self.surface, shading)
                    lit, low, clip = _aimed(elements, emitters, patches, st.shadow_passes, progress, emitting, st.faces_occlude, trees,
                                            self.reach)
                else:
                    lit, low, clip = _shadowed(elements, emitters, None, st.shadow_passes, progress, st.faces_occlude, trees,
                                               self.reach)
            else:
                lit, low, clip = np.zeros((n, 3)), np.zeros(n, dtype=bool), np.zeros(n)
                progress.advance(1 + st.shadow_passes)
            self._area_key, self._area = key, (lit, low, clip)
            direct = direct + lit
            negative |= low
            clipped += clip

        indirect = np.zeros((n, 3))
        albedo = np.asarray(shading.vertex_albedo, dtype=np.float64)
        last = direct
        for _ in range(bounces if shading.reflects else 0):
            radiance = albedo * last / math.pi
            if not np.any(radiance > 0):
                break
            last, low, clip = _shadowed(elements, None, radiance, st.shadow_passes, progress, st.faces_occlude,
                                        self._trees_for(bouncing), self.reach)  # fmt: skip
            indirect += last
            negative |= low
            clipped += clip
        progress.finish()
        for name, arr in (("direct", direct), ("indirect", indirect)):
            if not np.isfinite(arr).all() or arr.min(initial=0.0) < 0:
                raise NumericalError(f"{self.surface.source}: the disk transfer produced a {name} irradiance that is negative or not finite")
        k = self.keep  # the input's vertices (a reflecting ground's grid follows them)
        return LightResult(
            direct=direct[:k],
            indirect=indirect[:k],
            error=np.zeros((k, 3)),
            n_shadow_rays=rays,
            n_bounce_rays=0,
            lights=stats,
            samples=np.zeros(k, dtype=np.int64),
            seconds=time.perf_counter() - t0,
            contacts=contacts,
            negative=int(np.count_nonzero(negative[:k])),
            clipped=float(clipped[:k].sum()),
        )

    def _trees_for(self, needed: bool) -> _Trees | None:
        """The passes' trees (built on first need; None for the brute-force passes)."""
        st = self.settings
        if st.theta is None or not needed:
            return None
        if self._trees is None:
            self._trees = _Trees(self.elements, st.theta, st.aimed_tree, st.faces_occlude, st.share, st.near)
        return self._trees

    def _dome(self, lights):
        """(n, 3) direct irradiance of the domes, pi L (1 - A) with A the disk method's
        cosine-weighted occlusion (pi L without shadows; A computed once); None without a dome."""
        domes = [light for light in lights if light.kind == "dome" and not light.is_black]
        if not domes:
            return None
        surface = self.surface
        has_normal = np.any(np.asarray(surface.normals) != 0, axis=1).astype(np.float64)
        open_sky = sum((light.value for light in domes if not light.shadow), np.zeros(3))
        shadowed = sum((light.value for light in domes if light.shadow), np.zeros(3))
        out = math.pi * has_normal[:, None] * open_sky[None, :]
        if np.any(shadowed > 0):
            if self._ao is None:
                from .estimator import bunnell_ao

                options = replace(self.options, measure="cosine")
                self._ao = np.asarray(bunnell_ao(self.mesh, options, ground=self.ground))
                if surface is not self.mesh:  # the ground grid's points (the input's own AO: without the grid)
                    grid = np.asarray(bunnell_ao(surface, options, ground=self.ground))[self.keep :]
                    self._ao = np.concatenate([self._ao, grid])
            out = out + math.pi * (has_normal * self._ao)[:, None] * shadowed[None, :]
        return out


def _checked_lights(surface: Surface, lights) -> tuple:
    """``lights`` as :class:`Light` objects (``--light`` strings parsed); a bad one: an
    ``InputError`` naming the surface's file."""
    from ...io.lights import parse_light_spec
    from ...shading import Light

    out = []
    for k, light in enumerate(lights, 1):
        if isinstance(light, str):
            try:
                light = parse_light_spec(light, k)
            except ValueError as exc:
                raise InputError(surface.source, str(exc)) from None
        if not isinstance(light, Light):
            raise TypeError(f"light {k}: expected an aobake.shading.Light or a --light string, got {type(light).__name__}")
        out.append(light)
    return tuple(out)


def _area_key(lights, light_disks: int) -> tuple:
    """What the emitted light (area lights and emitting triangles) depends on among the
    lights: every field of each area light, as bytes where it is an array."""
    key = []
    for light in lights:
        if light.is_black or light.kind not in AREA_KINDS:
            continue
        key.append(tuple(np.asarray(getattr(light, f.name)).tobytes() if isinstance(getattr(light, f.name), np.ndarray)
                         else getattr(light, f.name) for f in fields(light)))  # fmt: skip
    return (light_disks, *key)


class _Trees:
    """The lit passes' trees and receivers of one scene (built once, used by every pass):
    both sides of every vertex as receivers, the vertex disks, the occluding triangles."""

    def __init__(self, elements: DiskElements, theta: float, aimed: tuple, faces_occlude: bool, share: bool = True,
                 near: float = 0.0):  # fmt: skip
        idx = elements.emitter_index
        self.positions = elements.positions
        self._cells = {}
        front_p, front_n, back_p, back_n = _sides(elements)
        self.theta, self.aimed = theta, aimed  # (theta, edge) of the aimed pass's tree
        self.sides = (Receivers(front_p, front_n), Receivers(back_p, back_n))
        self.elements = elements
        self.vertex = DiskTree(elements.positions[idx], elements.normals[idx], elements.areas[idx], theta, near=near)
        self.own = np.full(elements.n_vertices, -1, dtype=np.int64)  # each vertex's own disk
        self.own[idx] = np.arange(idx.shape[0])
        # the passes that only weight the next one are evaluated at one vertex per leaf of
        # the vertex tree (the AO's pass representatives) and shared with the leaf
        rep_of = np.arange(elements.n_vertices, dtype=np.int64)
        if self.vertex.size and share:
            _h.leaf_representatives(elements.positions, elements.normals, elements.areas, idx[self.vertex.order],
                                    self.vertex.skip, self.vertex.start, self.vertex.stop, SHARE_COS, rep_of)  # fmt: skip
        self.reps, self.rep_index = np.unique(rep_of, return_inverse=True)
        self.shared = self.reps.shape[0] < elements.n_vertices
        if self.shared:
            self.rep_sides = (Receivers(front_p[self.reps], front_n[self.reps]), Receivers(back_p[self.reps], back_n[self.reps]))
            self.rep_own = self.own[self.reps]
        else:
            self.rep_sides, self.rep_own = self.sides, self.own
        if faces_occlude:
            self.faces, occ = _face_occluders(elements)
            self.occluders = DiskTree(occ[:, :3], occ[:, 3:6], occ[:, 6], theta, near=near)
            self.occ_own = np.full(len(self.faces), -1, dtype=np.int64)
        else:
            self.faces, self.occluders, self.occ_own = None, self.vertex, idx

    def vertex_cells(self, receivers: Receivers):
        """The vertex disks' near field at ``receivers`` (their barycentric cells:
        ``DiskTree.vertex_cells``, made on first use); None without one, and at the
        representatives (it changes nothing measurable there, docs/bunnell-light.md)."""
        if self.vertex.size == 0 or self.vertex.near <= 0.0 or receivers.n != self.elements.n_vertices:
            return None
        key = (id(receivers), 0)
        if key not in self._cells:
            self._cells[key] = self.vertex.vertex_cells(receivers, self.elements, self.elements.emitter_index)
        return self._cells[key]

    def cells(self, receivers: Receivers, facing: int):
        """The triangles' near field at ``receivers`` for the side ``facing`` (1: front, -1:
        back) that emits (``DiskTree.triangle_cells``, made on first use); None without
        one, and at the representatives (measured: the near field there makes the box's
        bounce worse, docs/bunnell-light.md)."""
        if self.faces is None or self.occluders.near <= 0.0 or receivers.n != self.elements.n_vertices:
            return None
        key = (id(receivers), 1)
        if key not in self._cells:
            self._cells[key] = self.occluders.triangle_cells(receivers, self.positions, self.faces)
        return self._cells[key][0 if facing > 0 else 1]


#: The reflecting ground's grid (:func:`ground_grid`): points a side, how far it reaches in
#: units of the surface's size, and how much finer its cells are at the centre than at the
#: rim (sinh spacing). Measured in docs/bunnell-light.md.
GROUND_POINTS = 81
GROUND_REACH = 256.0
GROUND_GROWTH = 7.5


def ground_grid(surface: Surface, shading: Shading, ground: Ground) -> tuple[Surface, Shading]:
    """``surface`` with a square grid of ground triangles appended in the plane (facing up,
    albedo ``ALBEDO``, not emitting), centred under it and reaching ``GROUND_REACH`` times
    its size (the larger of its half footprint and its height over the plane), its cells
    growing from the centre outwards; and ``shading`` extended to match. The surface's
    vertices, faces and normals come first, unchanged. Past the grid the plane occludes
    but does not reflect; where a triangle of the surface lies in the plane (a modelled
    floor) the grid has a hole: its points there, and the triangles that touch them, are
    left out (the reference's plane reflects only where nothing of the mesh lies in it; a
    grid coinciding with the floor would also bury the floor's receivers)."""
    from ...ground import ALBEDO
    from ...mesh import surface_from_arrays

    pos = np.asarray(surface.positions, dtype=np.float64)
    up = int(ground.axis)
    u, v = {0: (1, 2), 1: (2, 0), 2: (0, 1)}[up]  # e_u x e_v = e_up: the triangles face up
    lo, hi = pos.min(axis=0), pos.max(axis=0)
    size = max(0.5 * (hi[u] - lo[u]), 0.5 * (hi[v] - lo[v]), hi[up] - float(ground.height))
    size = size if size > 0 else 1.0
    t = np.sinh(GROUND_GROWTH * np.linspace(-1.0, 1.0, GROUND_POINTS)) / math.sinh(GROUND_GROWTH) * GROUND_REACH * size
    gu, gv = np.meshgrid(0.5 * (lo[u] + hi[u]) + t, 0.5 * (lo[v] + hi[v]) + t, indexing="ij")
    grid = np.zeros((GROUND_POINTS * GROUND_POINTS, 3))
    grid[:, u], grid[:, v], grid[:, up] = gu.ravel(), gv.ravel(), float(ground.height)
    i, j = np.meshgrid(np.arange(GROUND_POINTS - 1), np.arange(GROUND_POINTS - 1), indexing="ij")
    a = (i * GROUND_POINTS + j).ravel()
    b, c, d = a + GROUND_POINTS, a + GROUND_POINTS + 1, a + 1  # (i+1, j), (i+1, j+1), (i, j+1)
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])]) + surface.n_vertices
    normal = np.zeros((len(grid), 3))
    normal[:, up] = 1.0
    covered = _under_a_floor(pos, np.asarray(surface.faces), float(ground.height), up, u, v, gu.ravel(), gv.ravel())
    faces = faces[~np.any(covered[faces - surface.n_vertices], axis=1)]  # a hole where a floor is modelled
    joined = surface_from_arrays(np.concatenate([pos, grid]), np.concatenate([np.asarray(surface.faces), faces]),
                                 np.concatenate([np.asarray(surface.normals, dtype=np.float64), normal]),
                                 name="ground", source=surface.source)  # fmt: skip
    grey_f, grey_v = np.full((len(faces), 3), ALBEDO), np.full((len(grid), 3), ALBEDO)
    grey_v[covered] = 0.0  # a floor modelled in the plane reflects there, with its own albedo
    return joined, replace(
        shading,
        face_albedo=np.concatenate([np.asarray(shading.face_albedo, dtype=np.float64), grey_f]),
        face_emission=np.concatenate([np.asarray(shading.face_emission, dtype=np.float64), np.zeros_like(grey_f)]),
        vertex_albedo=np.concatenate([np.asarray(shading.vertex_albedo, dtype=np.float64), grey_v]),
        vertex_emission=np.concatenate([np.asarray(shading.vertex_emission, dtype=np.float64), np.zeros_like(grey_v)]),
    )


def _under_a_floor(pos, faces, height, up, u, v, gu, gv) -> np.ndarray:
    """(N^2,) bool: the points of the tensor grid (``gu``, ``gv``) inside
    a triangle of ``faces`` whose corners all lie in the plane (within 1e-9 of the extent)."""
    out = np.zeros(gu.shape[0], dtype=bool)
    if faces.shape[0] == 0:
        return out
    tol = 1e-9 * max(float(np.ptp(pos, axis=0).max()), 1.0)
    on = np.abs(pos[:, up] - height) <= tol  # per vertex: no (m, 3, 3) copy of a large mesh
    flat = faces[np.all(on[faces], axis=1)]
    if flat.shape[0] == 0:
        return out
    cu, cv = pos[flat][:, :, u], pos[flat][:, :, v]
    xs, ys = np.unique(gu), np.unique(gv)  # the grid's coordinates along u and v
    i0, i1 = np.searchsorted(xs, cu.min(axis=1)), np.searchsorted(xs, cu.max(axis=1), side="right")
    j0, j1 = np.searchsorted(ys, cv.min(axis=1)), np.searchsorted(ys, cv.max(axis=1), side="right")
    n = ys.shape[0]
    for f in np.flatnonzero((i1 > i0) & (j1 > j0)):
        ii, jj = np.meshgrid(np.arange(i0[f], i1[f]), np.arange(j0[f], j1[f]), indexing="ij")
        px, py = xs[ii.ravel()], ys[jj.ravel()]
        (ax, bx, cx), (ay, by, cy) = cu[f], cv[f]
        d1 = (px - bx) * (ay - by) - (ax - bx) * (py - by)
        d2 = (px - cx) * (by - cy) - (bx - cx) * (py - cy)
        d3 = (px - ax) * (cy - ay) - (cx - ax) * (py - ay)
        inside = ~((np.minimum(np.minimum(d1, d2), d3) < 0) & (np.maximum(np.maximum(d1, d2), d3) > 0))
        out[(ii.ravel() * n + jj.ravel())[inside]] = True
    return out


def _gather(points, normals, centres, disk_normals, areas, radiance, own, reach=math.inf) -> np.ndarray:
    """(n, 3) irradiance at the receivers from one-sided disks, every pair summed (the
    brute-force :func:`~aobake.methods.bunnell.transfer.transfer`; the step a tree replaces)."""
    return transfer(points, normals, centres, disk_normals, areas, radiance, own, reach)


def _shadowed(
    elements: DiskElements, emitters: EmitterDisks | None, radiance, passes: int, progress, faces_occlude: bool = True,
    trees: _Trees | None = None, reach: float = math.inf,
) -> tuple:  # fmt: skip
    """Irradiance at the vertices (front side) from ``emitters`` (or, ``radiance`` (n, 3):
    the vertices' own disks reflecting), shadowed by the triangles (``faces_occlude``;
    else the vertex disks, as published) in ``passes`` passes; and a bool mask of the
    vertices it took below zero (set to 0), and each vertex's negative parts' summed magnitude.

    Pass 0 distributes the light unshadowed to both sides of every vertex. Pass k
    subtracts, at each receiver, ``G E_{k-1}`` of every vertex disk (two-sided: an
    occluder blocks from either side), ``E_{k-1}`` the light pass k - 1 left on the disk's
    side facing away from the receiver (what the disk stands in front of), ``G`` the
    transfer's ``A |cos_e| cos_r / (pi r^2 + A)``. With ``trees`` the vertex disks' light
    and the subtraction go through them (``lighttree.tree_gather``); else every pair.
    ``reach``: vertex disks and occluders farther from a receiver give and block nothing
    (``--max-distance``, normalised units); the emitters (lights) are not capped."""
    idx = elements.emitter_index
    n = elements.n_vertices
    front_p, front_n, back_p, back_n = _sides(elements)
    if trees is not None:
        # the front at every vertex (the output); what only weights the next pass (the back,
        # and the front before the last pass) at the representatives when shared
        shared = trees.shared and passes > 0
        first_f = _gather(front_p, front_n, *_emitting(emitters)) if emitters is not None else tree_gather(
            trees.vertex, trees.sides[0], radiance[idx], own=trees.own, cells=trees.vertex_cells(trees.sides[0]), reach=reach)
        rep_f = first_f[trees.reps] if shared else first_f
        back = trees.rep_sides[1] if shared else trees.sides[1]
        rep_b = _gather(back.points, back.normals, *_emitting(emitters)) if emitters is not None else tree_gather(
            trees.vertex, back, radiance[idx], own=trees.rep_own if shared else trees.own, cells=trees.vertex_cells(back),
            reach=reach)
        progress.advance(1)
        e_f, e_b = rep_f, rep_b
        for k in range(passes):
            # a receiver in front of occluder j is shadowed from the light on j's back, and v.v.
            if shared:
                e_f, e_b = e_f[trees.rep_index], e_b[trees.rep_index]
            if faces_occlude:
                w_back = np.maximum(e_b, 0.0)[trees.faces].mean(axis=1) / math.pi
                w_front = np.maximum(e_f, 0.0)[trees.faces].mean(axis=1) / math.pi
                own = None
            else:
                w_back, w_front = np.maximum(e_b[idx], 0.0) / math.pi, np.maximum(e_f[idx], 0.0) / math.pi
                own = trees.own
            last = k == passes - 1
            if last:  # the front at every vertex is the output
                front = trees.sides[0]
                e_f = first_f - tree_gather(trees.occluders, front, w_back, own=own, cells=trees.cells(front, 1),
                                            reach=reach) - tree_gather(
                    trees.occluders, front, w_front, flip=True, own=own, cells=trees.cells(front, -1), reach=reach)
            else:
                sides = trees.rep_sides if shared else trees.sides
                own_s = None if own is None else (trees.rep_own if shared else own)
                e_f, e_b = (first - tree_gather(trees.occluders, side, w_back, own=own_s, cells=trees.cells(side, 1), reach=reach)
                            - tree_gather(trees.occluders, side, w_front, flip=True, own=own_s, cells=trees.cells(side, -1),
                                          reach=reach)
                            for first, side in zip((rep_f, rep_b), sides, strict=True))  # fmt: skip
            progress.advance(1)
        if passes == 0:
            e_f = first_f
    else:
        if emitters is not None:
            src = (*_emitting(emitters), math.inf)
        else:
            src = (elements.positions[idx], elements.normals[idx], elements.areas[idx], radiance[idx], idx, reach)
        first_f = _gather(front_p, front_n, *src)
        first_b = _gather(back_p, back_n, *src)
        progress.advance(1)
        e_f, e_b = first_f, first_b
        if faces_occlude:
            faces, occ = _face_occluders(elements)
            centres = np.concatenate([occ[:, :3]] * 2)
            normals = np.concatenate([occ[:, 3:6], -occ[:, 3:6]])
            areas = np.concatenate([occ[:, 6]] * 2)
            own = np.full(2 * len(faces), -1, dtype=np.int64)
        else:
            centres = np.concatenate([elements.positions[idx]] * 2)
            normals = np.concatenate([elements.normals[idx], -elements.normals[idx]])
            areas = np.concatenate([elements.areas[idx]] * 2)
            own = np.concatenate([idx, idx])
        for _ in range(passes):
            if faces_occlude:
                weight = np.concatenate([np.maximum(e_b, 0.0)[faces].mean(axis=1), np.maximum(e_f, 0.0)[faces].mean(axis=1)]) / math.pi
            else:
                weight = np.concatenate([np.maximum(e_b[idx], 0.0), np.maximum(e_f[idx], 0.0)]) / math.pi
            e_f = first_f - _gather(front_p, front_n, centres, normals, areas, weight, own, reach)
            e_b = first_b - _gather(back_p, back_n, centres, normals, areas, weight, own, reach)
            progress.advance(1)
    low = np.any(e_f < 0.0, axis=1) if n else np.zeros(0, dtype=bool)
    return np.maximum(e_f, 0.0), low, -np.minimum(e_f, 0.0).sum(axis=1)


def _emitting(emitters: EmitterDisks) -> tuple:
    """``_gather``'s disk arguments for ``emitters`` (owned by no receiver)."""
    return emitters.centres, emitters.normals, emitters.areas, emitters.radiance, np.full(emitters.size, -1, dtype=np.int64)


def _merged(disks: EmitterDisks, count: int) -> EmitterDisks:
    """``disks`` with each group of more than ``count`` disks (the emitting triangles, at
    least one disk each) merged into ``count`` patches along a Morton order: summed
    area, area-weighted centre, normal and radiance."""
    keep, merged = [], []
    for g in range(disks.n_groups):
        sel = np.flatnonzero(disks.group == g)
        if sel.size <= count:
            keep.append(sel)
            continue
        c = disks.centres[sel]
        lo, span = c.min(axis=0), np.ptp(c, axis=0).max() or 1.0
        q = np.minimum(((c - lo) / span * 1024).astype(np.int64), 1023)
        key = np.zeros(sel.size, dtype=np.int64)
        for bit in range(10):
            for axis in range(3):
                key |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
        order = sel[np.argsort(key, kind="stable")]
        for chunk in np.array_split(order, count):
            a = disks.areas[chunk]
            w = a / a.sum()
            m = (disks.normals[chunk] * a[:, None]).sum(axis=0)
            norm = np.linalg.norm(m)
            merged.append((w @ disks.centres[chunk], m / norm if norm > 0 else disks.normals[chunk[0]], a.sum(),
                           w @ disks.radiance[chunk], g))  # fmt: skip
    idx = np.concatenate(keep) if keep else np.zeros(0, dtype=np.int64)
    if not merged:
        return disks
    return EmitterDisks(
        np.concatenate([disks.centres[idx], [m[0] for m in merged]]),
        np.concatenate([disks.normals[idx], [m[1] for m in merged]]),
        np.concatenate([disks.areas[idx], [m[2] for m in merged]]),
        np.concatenate([disks.radiance[idx], [m[3] for m in merged]]),
        np.concatenate([disks.group[idx], [m[4] for m in merged]]).astype(np.int64),
    )


def _emitting_vertices(surface: Surface, shading: Shading):
    """(n,) bool: the vertices of emitting triangles, or None without any."""
    on = np.any(np.asarray(shading.face_emission) > 0, axis=1)
    if not on.any():
        return None
    out = np.zeros(surface.n_vertices, dtype=bool)
    out[np.asarray(surface.faces)[on].ravel()] = True
    return out


def _face_occluders(elements: DiskElements):
    """(faces (m', 3), rows (m', 7)): the triangles of nonzero area as occluders, each
    row its centroid, unit normal and area (the light on a side: its corners' mean)."""
    corner = elements.positions[elements.faces]
    cross = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    length = np.linalg.norm(cross, axis=1)
    ok = np.flatnonzero(length > 0)
    rows = np.column_stack([corner[ok].mean(axis=1), cross[ok] / length[ok][:, None], 0.5 * length[ok]])
    return elements.faces[ok], np.ascontiguousarray(rows)


def _sides(elements: DiskElements):
    """Receivers on both sides of every vertex: (front points, normals, back points, normals)."""
    lift = NEAR_OFFSET_REL * np.sqrt(elements.areas)[:, None] * elements.normals
    return elements.points, elements.normals, elements.positions - lift, -elements.normals


def _aimed(
    elements: DiskElements, emitters: EmitterDisks, patches: EmitterDisks, passes: int, progress, emitting=None,
    faces_occlude: bool = True, trees: _Trees | None = None, reach: float = math.inf,
) -> tuple:  # fmt: skip
    """Irradiance at the vertices (front side) from ``emitters``, shadowed by the vertex
    disks in ``passes`` passes aimed at the lights; the vertices taken below zero and each
    vertex's negative parts' summed magnitude.

    Pass 0 distributes each light's disks unshadowed, U, to both sides of every vertex.
    Pass k subtracts at each receiver, for every vertex disk whose line from the
    receiver meets a light beyond it, ``pi G L v``: L the light's radiance there, v the
    fraction of that light pass k - 1 left on the disk's side facing the light (1 in the
    first: Bunnell's second pass weights occluders by their own accessibility alike).
    ``emitting`` (n,) bool: vertices of emitting triangles, which do not shadow the
    emitting triangles' light (the last group): they lie in it. ``faces_occlude``: the
    occluders are the triangles (centroid, normal, area; a side's light the mean of its
    corners'), which tile the surface, rather than the vertex disks, whose circles
    leave gaps and overhang edges (direct light on the box: 4.6% against 10.6%). With
    ``trees`` each receiver walks the occluders' tree (``lighttree.aimed_shadow_tree``).
    ``reach``: occluders farther from a receiver block nothing (``--max-distance``)."""
    idx = elements.emitter_index
    n, n_groups = elements.n_vertices, emitters.n_groups
    front_p, front_n, back_p, back_n = _sides(elements)
    first = np.zeros((2, n, n_groups, 3))
    for g in range(n_groups):
        sel = emitters.group == g
        src = (emitters.centres[sel], emitters.normals[sel], emitters.areas[sel], emitters.radiance[sel],
               np.full(int(sel.sum()), -1, dtype=np.int64))  # fmt: skip
        first[0, :, g] = _gather(front_p, front_n, *src)
        first[1, :, g] = _gather(back_p, back_n, *src)
    progress.advance(1)
    if trees is not None:
        faces, occ, occ_own = trees.faces, None, trees.occ_own
    elif faces_occlude:
        faces, occ = _face_occluders(elements)
        occ_own = np.full(len(faces), -1, dtype=np.int64)
    else:
        occ = np.column_stack([elements.positions[idx], elements.normals[idx], elements.areas[idx]])
        occ_own = idx
    occ = None if occ is None else np.ascontiguousarray(occ)
    rows = np.column_stack([patches.centres, patches.normals, patches.areas, patches.radiance, patches.group])
    rows = np.ascontiguousarray(rows, dtype=np.float64)
    lit = first
    blocked = np.empty((n, n_groups))
    for _ in range(passes):
        u = first.sum(axis=-1)
        e = np.maximum(lit, 0.0).sum(axis=-1)
        vis = np.where(u > 0.0, np.minimum(e / np.where(u > 0.0, u, 1.0), 1.0), 0.0)  # (side, n, group)
        if emitting is not None:
            vis[:, emitting, n_groups - 1] = 0.0
        if faces_occlude:
            vis = vis[:, faces].mean(axis=2)
        else:
            vis = vis[:, idx]
        vis = np.ascontiguousarray(vis.transpose(1, 0, 2))  # (k, side, group)
        lit = np.empty_like(first)
        last = _ == passes - 1  # the last pass lights the front sides alone: they are the output
        for side, (pts, nrm) in enumerate(((front_p, front_n),) if last else ((front_p, front_n), (back_p, back_n))):
            if trees is not None and not last and trees.reps.shape[0] < n:
                part = np.empty((trees.reps.shape[0], n_groups))
                aimed_shadow_tree(pts[trees.reps], nrm[trees.reps], trees.occluders, occ_own, vis, rows, part, *trees.aimed,
                                  reach=reach)
                blocked[:] = part[trees.rep_index]
            elif trees is not None:
                aimed_shadow_tree(pts, nrm, trees.occluders, occ_own, vis, rows, blocked, *trees.aimed, reach=reach)
            else:
                _kls.aimed_shadow(pts, nrm, occ, occ_own, vis, rows, reach * reach, blocked)
            lit[side] = first[side] * (1.0 - blocked)[:, :, None]
        progress.advance(1)
    low = np.any(lit[0] < 0.0, axis=(1, 2)) if n else np.zeros(0, dtype=bool)
    return np.maximum(lit[0], 0.0).sum(axis=1), low, -np.minimum(lit[0], 0.0).sum(axis=(1, 2))


def emitter_disks(elements: DiskElements, shading: Shading, lights=(), light_disks: int = LIGHT_DISKS) -> EmitterDisks:
    """The emitting disks of ``lights``' rect, disk and sphere lights (not treated as
    points) and of ``shading``'s emitting triangles, in ``elements``' frame: each light cut
    into about ``light_disks`` cells of equal area, each emitting triangle into s^2
    similar triangles (about ``light_disks`` over all of them), a disk at each centre."""
    parts = []
    to_local = lambda x: (np.asarray(x, dtype=np.float64) - elements.origin) / elements.scale  # noqa: E731
    for light in lights:
        if light.is_black or light.kind not in AREA_KINDS:
            continue
        g = len(parts)
        if light.kind == "rect":
            s = max(1, round(math.sqrt(light_disks)))
            t = (2.0 * np.arange(s) + 1.0) / s - 1.0
            a, b = (x.ravel() for x in np.meshgrid(t, t, indexing="ij"))
            centres = light.position + a[:, None] * light.u + b[:, None] * light.v
            normals = np.broadcast_to(light.normal, centres.shape)
        elif light.kind == "disk":
            s = max(1, round(math.sqrt(light_disks)))
            t = (np.arange(s) + 0.5) / s
            ex, ey, ez, fx, fy, fz = _warps.frame(*map(float, light.normal))
            e, f = np.array([ex, ey, ez]), np.array([fx, fy, fz])
            xy = np.array([_warps.square_to_uniform_disk_concentric(u0, u1) for u0 in t for u1 in t])
            centres = light.position + light.radius * (xy[:, :1] * e + xy[:, 1:] * f)
            normals = np.broadcast_to(light.normal, centres.shape)
        else:  # sphere: a Fibonacci lattice of equal-area cells, each facing outward
            k = max(1, light_disks)
            z = 1.0 - (2.0 * np.arange(k) + 1.0) / k
            phi = np.arange(k) * math.pi * (3.0 - math.sqrt(5.0))
            rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
            normals = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
            centres = light.position + light.radius * normals
        parts.append((to_local(centres), np.asarray(normals), np.full(len(centres), light.area / len(centres) / elements.scale**2),
                      np.broadcast_to(light.value, centres.shape), np.full(len(centres), g)))  # fmt: skip
    emitting = _emitting_triangles(elements, shading, light_disks, len(parts))
    if emitting is not None:
        parts.append(emitting)
    if not parts:
        z3 = np.zeros((0, 3))
        return EmitterDisks(z3, z3, np.zeros(0), z3, np.zeros(0, dtype=np.int64))
    fields = [np.ascontiguousarray(np.concatenate([p[i] for p in parts]), dtype=np.float64) for i in range(4)]
    group = np.concatenate([p[4] for p in parts]).astype(np.int64)
    return EmitterDisks(*fields, group)


def _emitting_triangles(elements: DiskElements, shading: Shading, light_disks: int, group: int):
    """(centres, normals, areas, radiance, group) of the emitting triangles cut into s^2
    similar triangles each (normalised frame); None without any."""
    emission = np.asarray(shading.face_emission, dtype=np.float64)
    faces = elements.faces
    if faces.size == 0:
        return None
    corner = elements.positions[faces]
    cross = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    length = np.linalg.norm(cross, axis=1)
    on = np.flatnonzero(np.any(emission > 0, axis=1) & (length > 0))
    if on.size == 0:
        return None
    area = 0.5 * length[on]
    target = area.sum() / max(1, light_disks)
    steps = np.clip(np.ceil(np.sqrt(area / target)), 1, 64).astype(np.int64)
    out = []
    for s in np.unique(steps):
        rows = on[steps == s]
        # barycentric centroids of the s^2 sub-triangles: s(s+1)/2 upright, s(s-1)/2 inverted
        i, j = np.triu_indices(s)
        j = j - i
        up = np.stack([i + 1 / 3, j + 1 / 3], axis=1)[i + j <= s - 1]
        down = np.stack([i + 2 / 3, j + 2 / 3], axis=1)[i + j <= s - 2]
        bary = np.concatenate([up, down]) / s
        c = corner[rows]
        pts = c[:, None, 0] + bary[None, :, :1] * (c[:, None, 1] - c[:, None, 0]) + bary[None, :, 1:] * (c[:, None, 2] - c[:, None, 0])
        k = bary.shape[0]
        unit = cross[rows] / length[rows][:, None]
        out.append((pts.reshape(-1, 3), np.repeat(unit, k, axis=0), np.repeat(0.5 * length[rows] / k, k), np.repeat(emission[rows], k, axis=0)))
    fields = [np.concatenate([o[i] for o in out]) for i in range(4)]
    return (*fields, np.full(len(fields[2]), group))


class _ShadowRays:
    """What the point, spot and distant lights' shadow rays need that no light changes:
    the Embree scene, and (on first use) the contact-safe origins and the rays' offsets."""

    def __init__(self, surface: Surface, options: BunnellOptions, ground: Ground | None):
        self.surface, self.ground = surface, ground
        self.tracer = tracer = tracer_for(surface.positions, surface.faces)
        self.points = np.ascontiguousarray(tracer.local)
        self.normals = np.ascontiguousarray(surface.normals, dtype=np.float64)
        tmax = math.inf if options.max_distance is None else float(options.max_distance)
        self.far_cap = min(tmax / float(tracer.scale), INFINITE_DISTANCE)
        self._origins = None

    def origins(self) -> tuple:
        """(origins, contacts, faces, shorten): the shadow rays' contact-safe origins, the
        contacts found, the faces (int64) and each face's self-hit margin."""
        if self._origins is None:
            surface, tracer = self.surface, self.tracer
            edges = _topo.longest_edges(surface.positions, surface.faces)
            offsets = ray_offsets(surface, tracer.magnitude, None, edges)
            origins, contacts = contact_origins(surface, tracer, offsets, edges)
            faces = np.ascontiguousarray(surface.faces, dtype=np.int64)
            face_edges = edges[faces].max(axis=1) if faces.size else np.zeros(0)
            shorten = RAY_OFFSET_ULPS * EPS32 * (tracer.magnitude + face_edges)
            self._origins = (origins, contacts, faces, shorten)
        return self._origins


class _GridRays:
    """:class:`_ShadowRays` for the ground grid's points (facing up, in the plane): the
    input's Embree scene, origins lifted off the plane by the float32 rounding of their
    magnitude (no contacts: the plane is not in the scene)."""

    def __init__(self, rays: _ShadowRays, positions):
        self.tracer, self.ground, self.far_cap = rays.tracer, rays.ground, rays.far_cap
        self.points = np.ascontiguousarray(np.asarray(positions, dtype=np.float64) - rays.tracer.center)
        self.normals = np.zeros_like(self.points)
        self.normals[:, rays.ground.axis] = 1.0
        lift = RAY_OFFSET_ULPS * EPS32 * (rays.tracer.magnitude + np.abs(self.points).max(axis=1))
        self._origins = (rays.tracer.frame(self.points + lift[:, None] * self.normals), 0,
                         np.zeros((1, 3), dtype=np.int64), np.zeros(1))  # fmt: skip

    def origins(self) -> tuple:
        return self._origins


def _exact_direct(rays: _ShadowRays, lights):
    """Direct irradiance (n, 3) of the point, spot and distant lights (one with an angle
    taken along its axis) by one shadow ray per light and vertex in reach (the reference's kernels and contact-safe origins),
    per-light :class:`LightStats`, the contacts and the rays cast."""
    tracer, points, normals, ground = rays.tracer, rays.points, rays.normals, rays.ground
    n = points.shape[0]
    n_lights = len(lights)
    out = np.zeros((n, 3))
    # a distant light with an angle: its axis alone (E_perp cos, exact for a sharp one)
    lights = tuple(replace(light, angle=0.0) if light.kind == "distant" else light for light in lights)
    exact = np.array([not light.is_black and light.kind in ("point", "spot", "distant") for light in lights], dtype=bool)
    kinds, params = _kl.light_table(lights, tracer.center)
    reach = _kl.reach_all(points, normals, kinds, params) if n_lights else np.zeros((n, 0), dtype=np.int8)
    black = np.array([light.is_black for light in lights], dtype=bool)
    reach[:, black] = _kl.REACH_NONE
    contacts = 0
    cast = np.zeros(n_lights + 1, dtype=np.int64)
    if exact.any():
        origins, contacts, faces, shorten = rays.origins()
        scale = float(tracer.scale)
        far_cap = rays.far_cap
        emission = np.zeros((max(1, faces.shape[0]), 3))
        keys = _k.vertex_keys(np.uint64(0), n)  # exact lights draw nothing from them
        j_lo = np.zeros(n_lights + 1, dtype=np.int64)
        j_hi = np.concatenate([exact, [False]]).astype(np.int64)
        g_axis, g_height = -1, 0.0
        if ground is not None:
            g_axis = int(ground.axis)
            g_height = (float(ground.height) - float(tracer.center[g_axis])) / scale
        per = int(exact.sum())
        block = max(1, BLOCK_RAYS // per)
        k = min(block, n) * per
        org = np.empty((k, 3), dtype=np.float32)
        dirs = np.empty((k, 3), dtype=np.float32)
        far = np.empty(k, dtype=np.float32)
        w = np.empty((k, 3))
        row = np.empty(k, dtype=np.int64)
        comp = np.empty(k, dtype=np.int64)
        on_plane = np.empty(k, dtype=np.uint8)
        sums = np.zeros((n, n_lights + 1, 3))
        squares = np.zeros((n, n_lights + 1, 3))
        vidx = np.arange(n, dtype=np.int64)
        for b in range(0, n, block):
            sub = vidx[b : b + block]
            m = _kl.direct_samples(
                sub, points, origins, normals, keys, kinds, params, j_lo, j_hi, reach,
                points, faces, np.zeros(1, dtype=np.int64), np.ones(1), emission, 1.0, shorten, scale, far_cap,
                sums[b : b + block], squares[b : b + block], org, dirs, far, w, row, comp,
            )  # fmt: skip
            if m:
                if ground is not None:
                    _kl.ground_shadows(org, dirs, far, m, g_axis, g_height, on_plane)
                ids = tracer.occluded_within(org[:m], dirs[:m], far[:m])
                if ground is not None:
                    ids = np.where(on_plane[:m] != 0, 0, ids)
                _kl.add_samples(ids, w, row, comp, m, sums[b : b + block], squares[b : b + block])
                cast += np.bincount(comp[:m], minlength=n_lights + 1)
        out = sums.sum(axis=1)
    stats = []
    for c, light in enumerate(lights):
        if light.is_black:
            stats.append(LightStats(light.name))
            continue
        codes = np.bincount(reach[:, c].astype(np.int64), minlength=5)
        stats.append(LightStats(light.name, int(codes[1]), int(codes[2]), int(codes[3]), int(codes[4]), int(cast[c])))
    stats.append(LightStats("emitters"))
    return out, tuple(stats), contacts, int(cast.sum())
