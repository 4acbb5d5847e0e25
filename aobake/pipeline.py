"""End-to-end flows used by the CLI and by Python users: load -> compute -> check -> write.

Parses no command-line options and never exits the process.
"""

from __future__ import annotations

import contextlib
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from time import perf_counter
from typing import Any

import numpy as np

from . import __version__
from ._types import AOArray
from .constants import DEFAULT_METERS_PER_UNIT, DEFAULT_UP_AXIS
from .errors import FormatError, InputError, NumericalError, OutputError
from .io import check_output_dir, usd_output_mode
from .io.common import check_not_input, output_name
from .mesh import Surface
from .methods import METHODS
from .progress import CompileWatch, Progress, compile_note


@dataclass(frozen=True)
class BakeReport:
    """What a bake did, for the one-line summary and for scripts.

    Attributes
    ----------
    source, output : str
    method : str
    n_vertices : int
    n_rays : int
        Rays cast in total (0 for methods that cast none).
    seconds : float
        Compute time (loading, writing and compiling kernels excluded).
    contacts : int
        Vertices whose ray origin was mirrored at a contact (embree).
    options : dict
    field_skipped : tuple of int
        Per ``--field``, receivers beyond its r_far (not evaluated).
    field_seconds : float
        Time spent evaluating the fields (not in ``seconds``; compiling excluded).
    compile_seconds : float
        Time numba spent compiling kernels (a cold cache: the first run), in neither.
    note : str
        What the summary adds about the input, e.g. the time an animated USD was read at.
    """

    source: str
    output: str
    method: str
    n_vertices: int
    n_rays: int
    seconds: float
    contacts: int = 0
    options: dict = field(default_factory=dict)
    field_skipped: tuple = ()
    field_seconds: float = 0.0
    compile_seconds: float = 0.0
    note: str = ""

    def summary(self) -> str:
        """One line: vertices, rays, seconds, rays per second, compile time if any."""
        text = f"{self.source}: {self.n_vertices} vertices, {self.method}"
        if self.n_rays:
            rate = self.n_rays / self.seconds if self.seconds > 0 else float("inf")
            text += f", {self.n_rays / 1e6:.3f} M rays in {self.seconds:.2f} s ({rate / 1e6:.2f} M rays/s)"
        else:
            text += f" in {self.seconds:.2f} s"
        if self.contacts:
            text += f", {self.contacts} contact vertices"
        if self.field_skipped:
            skipped = " + ".join(str(k) for k in self.field_skipped)
            text += (
                f", x {len(self.field_skipped)} field(s) in {self.field_seconds:.2f} s"
                f" ({skipped} receivers beyond r_far)"
            )
        if self.note:
            text += f", {self.note}"
        return text + compile_note(self.compile_seconds) + f" -> {self.output}"


def as_surface(mesh: Any, time: float | None = None, prepare=None) -> Surface:
    """A :class:`Surface` from a path, a ``trimesh.Trimesh``/``Scene``, or a Surface
    (``time``: the USD time code to read a path at; ``prepare``: see
    :func:`aobake.io.load_mesh`, called for a path only)."""
    if isinstance(mesh, (str, Path)):
        from .io import load_mesh

        return load_mesh(mesh, time=time, prepare=prepare)
    if time is not None:
        raise ValueError("time applies to USD files only; got a loaded mesh")
    if isinstance(mesh, Surface):
        return mesh
    from .io.trimesh_formats import mesh_from_trimesh

    return mesh_from_trimesh(mesh)


def _compute(surface: Surface, method: str, options: dict, progress: Progress | None, vertices=None, ground=None):
    """``(ao, n_rays, contacts, attributes)`` of ``method`` on ``vertices`` (None: all), a
    method's numerical error named after the file; ``ground``: a resolved
    :class:`aobake.ground.Ground` (None: none)."""
    from .methods import run

    extra = {} if ground is None else {"ground": ground}
    try:
        if vertices is None:  # the whole mesh: every method
            result = run(method, surface, options, progress, **extra)
        else:
            result = run(method, surface, options, progress, vertices=vertices, **extra)
    except NumericalError as exc:  # a method's own message, named after the file
        name = Path(surface.source).name
        if str(exc).startswith(f"{name}:"):
            raise
        raise NumericalError(f"{name}: {exc}") from None
    return result.ao, result.n_rays, result.contacts, result.attributes or {}


def bake(
    mesh: Any, method: str = "embree", *, progress: Progress | None = None, ground=None, **options
) -> AOArray:
    """Per-vertex ambient occlusion of a mesh, as accessibility (1 = open).

    Parameters
    ----------
    mesh : str, Path, trimesh.Trimesh, trimesh.Scene or Surface
        What to bake; a multi-mesh scene is one occluding scene.
    method : {"embree", "bunnell"}
        ``"embree"``: Monte Carlo ray casting (the reference). ``"bunnell"``: summed disk
        and polygon form factors over a cluster tree, no rays
        (:func:`aobake.methods.bunnell.bunnell_ao`: ``passes``, ``theta``, ``near``, ...).
    progress : Progress, optional
    ground : "auto", float or aobake.ground.Ground, optional
        An infinite occluding plane under the mesh, perpendicular to its up axis (the
        file's, else Y): at its lowest vertex ("auto") or at that height (mesh units).
    **options
        Passed to the method, e.g. ``n_rays``, ``measure``, ``max_distance``, ``bias``,
        ``seed``, ``tolerance``, ``threads`` for :func:`aobake.methods.embree.embree_ao`.

    Returns
    -------
    ao : (n,) float64 in [0, 1]
        1 - A per input vertex, in input order.

    Examples
    --------
    >>> import trimesh, aobake
    >>> ao = aobake.bake(trimesh.creation.box(), n_rays=16)
    >>> bool((ao == 1.0).all())  # a convex body does not occlude itself
    True
    """
    surface = as_surface(mesh)
    plane = _ground(surface, ground, None)
    ao, *_ = _compute(surface, method, options, progress, **_plane(plane))
    return ao


def _plane(ground) -> dict:
    """``{"ground": ground}`` for :func:`_compute`, or nothing without a plane."""
    return {} if ground is None else {"ground": ground}


def _ground(surface: Surface, ground, up_axis: str | None):
    """The :class:`aobake.ground.Ground` of ``ground`` (None, "auto", a height or a Ground)
    along ``up_axis`` (else the input's, else Y); a plane above a vertex is a SettingError."""
    if ground is None:
        return None
    from .ground import resolve_ground

    up = up_axis or surface.metadata.get("up_axis") or DEFAULT_UP_AXIS
    return resolve_ground(ground, surface.positions, up, surface.source)


def bake_file(
    source: str | Path,
    output: str | Path | Sequence[str | Path],
    *,
    method: str = "embree",
    color: bool = False,
    up_axis: str | None = None,
    meters_per_unit: float | None = None,
    progress: Progress | None = None,
    fields: Sequence = (),
    channel: str | None = None,
    weld: bool = False,
    time: float | None = None,
    overlay: bool | None = None,
    ground=None,
    receivers: Sequence[str] = (),
    occluders: Sequence[str] = (),
    effects: str | Sequence[str] = "auto",
    lights: Sequence = (),
    scene_lights: bool = True,
    split_irradiance: bool = False,
    exposure: float = 0.0,
    **options,
) -> BakeReport:
    """Load ``source``, bake it once, write ``output`` (.ply, .usda, .usdc, .usd, .usdz,
    .gltf or .glb) atomically.

    ``output`` may be several paths (one bake, several formats). Suffixes and
    directories are checked before loading or computing, so a typo fails at once;
    nothing is written unless the whole bake and every write succeed. ``up_axis`` and
    ``meters_per_unit`` (USD stage metrics) default to the input's own (USD, glTF),
    else "Y" and 1.0.

    ``fields``: ambient occlusion fields of rigid occluders placed around the mesh,
    each an :class:`~aobake.methods.fields.AOField` or a ``.npz`` path, alone or as
    ``(field, transform)`` with a (4, 4) rigid transform or ``(tx, ty, tz[, rx, ry,
    rz])`` (degrees, see :func:`~aobake.methods.fields.rigid_transform`). Loaded (and checked)
    before computing; the mesh's own AO from ``method`` is multiplied by every
    field's 1 - A_k (:func:`~aobake.methods.fields.fields_ao`).

    ``channel`` (``"R"``, ``"G"``, ``"B"``, ``"A"``): write ``ao`` into that channel of
    the input's vertex colours (PLY and glTF), other channels kept. ``weld``: bake the
    mesh with coincident vertices of each part merged
    (:func:`aobake.mesh.weld_vertices`), written back per input vertex.

    USD input: ``time`` is the time code points and transforms are read at (default:
    USD's default time, see :func:`aobake.io.load_mesh`). A USD output of a USD input is
    an overlay layer over ``source`` unless ``overlay=False`` (a full flattened copy);
    ``.usdz`` is a flattened package (:func:`aobake.io.usd_output_mode`).

    ``receivers`` / ``occluders``: glob patterns over the parts (USD prim paths, else
    names; :mod:`aobake.selection`). Occluders not selected are left out of the scene
    (still written); receivers not selected keep the input's ``ao``, else 1.0.

    Light (:mod:`aobake.lighting`): ``effects`` ``"auto"`` computes what the scene calls
    for (direct light where it has lights or emitters, bounces where some albedo is
    above zero), or a list such as ``("ao", "direct")``; ``lights``: ``--light`` specs
    added to the file's own (``scene_lights=False`` ignores those). A lit bake also
    writes ``irradiance`` (and, with ``split_irradiance``, its direct and indirect
    terms); ``color`` then writes the lit colour at ``exposure`` stops. A scene without
    light bakes the AO alone, as if none of this existed.

    ``ground`` ("auto" or a height in mesh units): an infinite occluding plane
    perpendicular to the up axis that every AO method counts and nothing receives on
    (:mod:`aobake.ground`), recorded as ``ground=<height>`` in the outputs.

    Returns
    -------
    BakeReport
    """
    from . import lighting
    from .io import check_outputs
    from .io.usd import shared_stages
    from .selection import Selection

    outputs = _check_outputs(output, source, overlay)
    placed = _load_fields(fields)
    started: list = []  # the Embree scene, when it is built while the normals are computed
    prepare = None if weld or receivers or occluders else _scene_starter(method, started)
    with shared_stages():  # a USD scene's meshes, lights and materials from one open stage
        surface = as_surface(source, time, prepare)
        check_outputs(surface, outputs, channel)
        selection = Selection.of(surface, receivers, occluders)
        light = lighting.prepare(
            source, surface, method, options, effects=effects, lights=lights, scene_lights=scene_lights,
            split=split_irradiance, exposure=exposure,
        )  # fmt: skip
    plane = _ground(surface, ground, up_axis)
    part = _bake_range(
        surface, method, options, progress, None, weld=weld, selection=selection, light=light, ground=plane,
        started=started,
    )  # fmt: skip
    return _write(
        source, surface, outputs, [part], method, options, placed, color, up_axis, meters_per_unit,
        channel, weld, overlay, selection, light, plane,
    )  # fmt: skip


@dataclass(frozen=True)
class PartResult:
    """AO of a vertex range of one mesh (:func:`bake_part`), to be stitched by :func:`write_parts`.

    Attributes
    ----------
    vertices : (int, int)
        The range lo..hi-1.
    ao : (hi - lo,) float64
    n_rays, contacts : int
        Rays cast in the range; contact vertices of the whole mesh.
    seconds : float
        Compute time of the range (scene build included, compiling kernels not).
    compile_seconds : float
        Time spent compiling kernels (a cold numba cache), first run only.
    attributes : dict of str to array
        Extra per-vertex results of the range (``bentNormal``, ``irradiance``), written
        beside ``ao``.
    light : aobake.lighting.LightTotals or None
        Rays and time of a lit scene's light (its time is in ``seconds`` too).
    """

    vertices: tuple
    ao: Any
    n_rays: int
    contacts: int
    seconds: float
    compile_seconds: float = 0.0
    attributes: dict = field(default_factory=dict)
    light: Any = None


def bake_part(
    source: Any,
    *,
    method: str = "embree",
    vertices: tuple[int, int] | None = None,
    parts: tuple[int, int] | None = None,
    progress: Progress | None = None,
    receivers: Sequence[str] = (),
    occluders: Sequence[str] = (),
    effects: str | Sequence[str] = "auto",
    lights: Sequence = (),
    scene_lights: bool = True,
    ground=None,
    up_axis: str | None = None,
    **options,
) -> PartResult:
    """Bake one vertex range of ``source`` (a path or a surface) against the whole mesh.

    Give the range as ``vertices=(lo, hi)`` or as ``parts=(k, K)``: the k-th of K equal
    ranges (computed once the mesh is loaded). Only methods in
    :data:`aobake.methods.SPLITTABLE` bake ranges; a range of the whole mesh
    (``vertices=None, parts=None``) works for every method. ``receivers``,
    ``occluders``: as for :func:`bake_file` (give :func:`write_parts` the same). A lit
    scene (``effects``, ``lights``, ``scene_lights`` as for :func:`bake_file`) is baked
    whole: a range of it is an error. ``ground`` and ``up_axis``: as for :func:`bake_file`.
    """
    from . import lighting
    from .io.usd import shared_stages
    from .selection import Selection

    with shared_stages():  # a USD scene's meshes, lights and materials from one open stage
        surface = as_surface(source)
        if parts is not None:
            k, count = parts
            n = surface.n_vertices
            vertices = (n * k // count, n * (k + 1) // count)
        selection = Selection.of(surface, receivers, occluders)
        whole = vertices is None or tuple(vertices) == (0, surface.n_vertices)
        light = lighting.prepare(
            source, surface, method, options, effects=effects, lights=lights, scene_lights=scene_lights
        )
    if light is not None and not whole:
        raise InputError(
            surface.source, f"a lit scene ({light.plan.reasons['direct']}) is baked whole: bake it unsplit, or with --effects ao"
        )
    plane = _ground(surface, ground, up_axis)
    return _bake_range(surface, method, options, progress, vertices, selection=selection, light=light, ground=plane)


def write_parts(
    source: str | Path,
    output: str | Path | Sequence[str | Path],
    parts: Sequence[PartResult],
    *,
    method: str = "embree",
    color: bool = False,
    up_axis: str | None = None,
    meters_per_unit: float | None = None,
    fields: Sequence = (),
    surface: Surface | None = None,
    channel: str | None = None,
    time: float | None = None,
    overlay: bool | None = None,
    receivers: Sequence[str] = (),
    occluders: Sequence[str] = (),
    effects: str | Sequence[str] = "auto",
    lights: Sequence = (),
    scene_lights: bool = True,
    split_irradiance: bool = False,
    exposure: float = 0.0,
    ground=None,
    **options,
) -> BakeReport:
    """Stitch the ranges of :func:`bake_part` in order and write them like :func:`bake_file`.

    The ranges must cover the mesh's vertices exactly, in order; the files are then the
    bytes :func:`bake_file` writes with the same arguments (``seconds`` is the parts'
    sum, their compute time). ``surface``: ``source`` already loaded (not read again).
    """
    outputs = _check_outputs(output, source, overlay)
    placed = _load_fields(fields)
    surface = as_surface(source, time) if surface is None else surface
    expected = 0
    for part in parts:
        if part.vertices[0] != expected:
            raise ValueError(f"parts do not cover the vertices in order: {part.vertices} after {expected}")
        expected = part.vertices[1]
    if expected != surface.n_vertices:
        raise ValueError(f"parts cover {expected} of {surface.n_vertices} vertices")
    from . import lighting
    from .io import check_outputs
    from .selection import Selection

    check_outputs(surface, outputs, channel)
    selection = Selection.of(surface, receivers, occluders)
    light = None
    if any(p.light is not None for p in parts):  # a whole, lit part (bake_part refuses lit ranges)
        light = lighting.prepare(
            source, surface, method, options, effects=effects, lights=lights, scene_lights=scene_lights,
            split=split_irradiance, exposure=exposure,
        )  # fmt: skip
    plane = _ground(surface, ground, up_axis)
    return _write(
        source, surface, outputs, parts, method, options, placed, color, up_axis, meters_per_unit,
        channel, False, overlay, selection, light, plane,
    )  # fmt: skip


def _check_outputs(output, source, overlay: bool | None = None) -> list[Path]:
    """Output paths, with suffixes, USD output modes and directories checked before any
    work (none may be the input)."""
    outputs = [Path(output)] if isinstance(output, (str, Path)) else [Path(o) for o in output]
    if not outputs:
        raise ValueError("no output path given")
    usd_input = _is_usd(source)
    for path in outputs:
        usd_output_mode(path, usd_input, overlay)  # refuses an overlay it cannot write
        check_output_dir(path)
        check_not_input(path, [source])  # an overlay over its own source included
    return outputs


def _scene_starter(method: str, started: list):
    """A ``prepare`` for :func:`aobake.io.load_mesh` that starts building the Embree scene
    ``method`` will trace (:func:`aobake.tracing.start_scene`) and appends it to
    ``started``, for meshes of up to ``EARLY_SCENE_MAX_VERTICES`` vertices (the overlap
    costs memory); None for methods that trace no whole-surface scene."""
    from .constants import EARLY_SCENE_MAX_VERTICES
    from .methods import WHOLE_SCENE

    if method not in WHOLE_SCENE:
        return None

    def prepare(positions, faces) -> None:
        if positions.shape[0] <= EARLY_SCENE_MAX_VERTICES:
            from .tracing import start_scene

            started.append(start_scene(positions, faces))

    return prepare


def _bake_range(
    surface: Surface, method: str, options: dict, progress, vertices, *, weld: bool = False, selection=None,
    light=None, ground=None, started=(),
) -> PartResult:  # fmt: skip
    """Run ``method`` on ``vertices`` (None: all); compiling kernels is kept out of the time.
    ``weld``: bake the welded mesh (whole meshes only), results per input vertex.
    ``selection``: trace only its occluders, from its receivers (:func:`_compute_selected`).
    ``light``: a lit scene's :class:`aobake.lighting.LightJob`, computed on the same
    scene (whole meshes only), through the Embree scene the AO built (one, not two).
    ``ground``: a resolved plane every AO method counts. ``started``: Embree scenes
    already under way (:func:`_scene_starter`)."""
    from .tracing import shared_scenes

    totals = None
    welded = inverse = None
    with CompileWatch() as watch, shared_scenes(started):
        t0 = perf_counter()
        if weld:
            from .mesh import weld_vertices

            if vertices is not None:
                raise ValueError("a welded mesh is baked whole: weld takes no vertex range")
            welded, inverse = weld_vertices(surface)
            scene = welded if selection is None else selection.scene(welded)
            ao, n_rays, contacts, attributes = _compute(scene, method, options, progress, **_plane(ground))
            ao = np.asarray(ao)[inverse]
            attributes = {k: np.asarray(v)[inverse] for k, v in attributes.items()}
        elif selection is not None:
            ao, n_rays, contacts, attributes = _compute_selected(
                surface, method, options, progress, vertices, selection, **_plane(ground)
            )
        else:
            ao, n_rays, contacts, attributes = _compute(surface, method, options, progress, vertices, **_plane(ground))
        if light is not None and light.lit:
            attributes, totals = _compute_light(
                surface, method, options, progress, vertices, (welded, inverse), selection, light, attributes, ground
            )
        seconds = perf_counter() - t0 - watch.seconds
    lo, hi = (0, surface.n_vertices) if vertices is None else vertices
    return PartResult((lo, hi), ao, n_rays, contacts, seconds, watch.seconds, attributes, totals)


def _compute_light(surface, method, options, progress, vertices, welding, selection, light, attributes, ground=None):
    """A lit scene's irradiance attributes added to ``attributes``, on the scene the AO
    was traced on (``welding``: the AO's ``(welded surface, inverse)``, or Nones; the
    occluders only) and under its ``ground`` plane; and the light's ray totals."""
    from . import lighting

    if vertices is not None and tuple(vertices) != (0, surface.n_vertices):
        raise InputError(surface.source, "a lit scene is baked whole: it takes no vertex range")
    welded, inverse = welding
    scene = surface if welded is None else welded
    faces = None
    if selection is not None and not selection.occluders.all():
        faces = selection.kept_faces(surface)
        scene = selection.scene(scene)
    extra, totals = lighting.compute(
        light, scene, method, options, progress, faces=faces, inverse=inverse, ground=ground
    )
    return {**attributes, **extra}, totals


def _compute_selected(surface: Surface, method: str, options: dict, progress, vertices, selection, ground=None):
    """:func:`_compute` on the occluders' scene; a method that bakes vertex ranges bakes
    only the span of receiving vertices in ``vertices`` (the rest is replaced in
    :func:`_write`)."""
    from .methods import SPLITTABLE
    from .selection import unselected_values

    scene = selection.scene(surface)
    if method not in SPLITTABLE:
        return _compute(scene, method, options, progress, vertices, **_plane(ground))
    lo, hi = (0, surface.n_vertices) if vertices is None else vertices
    found = np.flatnonzero(selection.receiving(surface)[lo:hi])
    if found.size == 0:
        return np.ones(hi - lo), 0, 0, {}
    a, b = lo + int(found[0]), lo + int(found[-1]) + 1
    ao, n_rays, contacts, attributes = _compute(scene, method, options, progress, (a, b), **_plane(ground))
    full = np.ones(hi - lo)
    full[a - lo : b - lo] = ao
    padded = {}
    for name, values in attributes.items():
        padded[name] = unselected_values(name, surface, values)[lo:hi].copy()
        padded[name][a - lo : b - lo] = values
    return full, n_rays, contacts, padded


def _stitched_attributes(surface: Surface, parts) -> dict:
    """The parts' extra attributes concatenated; a range that baked no receiver (and so
    has none) holds what vertices not baked hold (:func:`aobake.selection.unselected_values`)."""
    from .selection import unselected_values

    out = {}
    for name in dict.fromkeys(k for p in parts for k in p.attributes):
        template = next(p.attributes[name] for p in parts if name in p.attributes)
        fill = unselected_values(name, surface, template)
        out[name] = np.concatenate(
            [p.attributes[name] if name in p.attributes else fill[p.vertices[0] : p.vertices[1]] for p in parts]
        )
    return out


def _write(
    source, surface, outputs, parts, method, options, placed, color, up_axis, meters_per_unit,
    channel=None, weld=False, overlay=None, selection=None, light=None, ground=None,
) -> BakeReport:  # fmt: skip
    """Fields applied, checks, every output written atomically (all or none)."""
    from .io import atomic_write, write_bake

    ao = parts[0].ao if len(parts) == 1 else np.concatenate([p.ao for p in parts])
    attributes = _stitched_attributes(surface, parts)
    seconds = sum(p.seconds for p in parts)
    skipped: tuple = ()
    with CompileWatch() as watch:
        t0 = perf_counter()
        if placed:
            ao, skipped = _apply_fields(surface, ao, placed, options.get("threads"))
        field_seconds = perf_counter() - t0 - watch.seconds
    if ao.shape != (surface.n_vertices,):
        raise NumericalError(f"{surface.source}: {method} returned {ao.shape} values for {surface.n_vertices} vertices")
    if selection is not None:  # receivers not selected keep the input's values
        from .selection import kept_ao, unselected_values

        idle = ~selection.receiving(surface)
        ao = np.where(idle, kept_ao(surface), ao)
        for name, values in attributes.items():
            attributes[name] = np.where(idle[:, None] if values.ndim == 2 else idle,
                                        unselected_values(name, surface, values), values)  # fmt: skip
    custom = {"method": method, "version": __version__, "source": Path(str(source)).name}
    custom.update({k: ("none" if v is None else v) for k, v in options.items() if k not in ("threads", "chunk_rays")})
    if placed:
        custom["fields"] = ", ".join(name for _, _, name in placed)  # USD customData takes no lists
    if weld:
        custom["weld"] = True
    if channel is not None:
        custom["channel"] = channel
    if ground is not None:
        custom["ground"] = float(ground.height)
    if selection is not None:
        custom.update(selection.provenance)
    display = None
    light_rays = 0
    note = _time_note(surface.metadata)
    if light is not None:
        from . import lighting

        custom.update(lighting.custom_data(light, options, method))
        if color:
            display = lighting.lit_colour(light, attributes[lighting.IRRADIANCE])
        totals = [p.light for p in parts if p.light is not None]
        total = lighting.LightTotals(
            sum(t.shadow_rays for t in totals), sum(t.path_rays for t in totals), sum(t.seconds for t in totals)
        )
        note = ", ".join(x for x in (note, lighting.summary(light, total)) if x)
        light_rays = total.shadow_rays + total.path_rays
    # Stage metrics: what the caller says, else what the input said (USD, glTF), else
    # the documented defaults. An unauthored metersPerUnit would mean centimetres.
    meta = surface.metadata
    # Every file goes to a temporary name first; all are renamed only once all are
    # written, so a failure (or Ctrl-C) in the second leaves no first behind either.
    with contextlib.ExitStack() as stack:
        for path in outputs:
            write_bake(
                stack.enter_context(atomic_write(path)),
                surface,
                np.asarray(ao),
                color=color,
                channel=channel,
                custom_data=custom,
                up_axis=up_axis or meta.get("up_axis") or DEFAULT_UP_AXIS,
                meters_per_unit=meters_per_unit or meta.get("meters_per_unit") or DEFAULT_METERS_PER_UNIT,
                overlay=overlay,
                attributes=attributes,
                display=display,
            )
    return BakeReport(
        source=Path(str(source)).name,
        output=", ".join(str(p) for p in outputs),
        method=method,
        n_vertices=surface.n_vertices,
        n_rays=sum(p.n_rays for p in parts) + light_rays,
        seconds=seconds,
        contacts=parts[0].contacts,
        options=dict(options),
        field_skipped=skipped,
        field_seconds=field_seconds if placed else 0.0,
        compile_seconds=watch.seconds + sum(p.compile_seconds for p in parts),
        note=note,
    )


def _is_usd(source: Any) -> bool:
    """Whether ``source`` is a USD file (by suffix) or a surface read from one."""
    from .io.usd_overlay import usd_source

    if isinstance(source, Surface):
        return usd_source(source) is not None
    return isinstance(source, (str, Path)) and Path(source).suffix.lower() in (".usd", ".usda", ".usdc", ".usdz")


def _time_note(meta: dict) -> str:
    """"2 animated meshes read at time 12" when a USD input has time samples, else ""."""
    animated = meta.get("animated", 0)
    if not animated:
        return ""
    when = "the default time" if meta.get("time") is None else f"time {meta['time']:g}"
    return f"{animated} animated mesh{'es' if animated > 1 else ''} read at {when}"


def compare_files(
    reference: str | Path,
    candidate: str | Path,
    *,
    threshold: float = 0.05,
    worst: int = 10,
    json_path: str | Path | None = None,
    plot_path: str | Path | None = None,
    render_path: str | Path | None = None,
    up: str | None = None,
):
    """Compare two bakes of the same mesh (PLY, USD, glTF or ``.npy``); ``reference`` is "a".

    Worst-vertex positions come from whichever file is a mesh. ``json_path`` and
    ``plot_path`` (PNG, needs matplotlib) are written atomically; their suffixes and
    directories are checked before anything is read.

    Returns
    -------
    aobake.tools.compare.Report
    """
    from .io import atomic_write, read_bake
    from .tools.compare import compare_ao, plot_compare

    for out in (json_path, plot_path, render_path):
        if out is not None:
            check_output_dir(out)
            check_not_input(out, (reference, candidate))
    if not (threshold >= 0 and math.isfinite(threshold)):
        raise ValueError(f"threshold must be a finite number >= 0, got {threshold!r}")
    for out in (plot_path, render_path):
        if out is not None and Path(out).suffix.lower() != ".png":
            raise FormatError(f"{Path(out).name}: images are written as PNG; use a .png suffix")
    if plot_path is not None:
        from .tools.plot import pyplot

        pyplot()  # before reading anything
    a = read_bake(reference)
    b = read_bake(candidate)
    positions = None
    for path, values in ((reference, a), (candidate, b)):
        if Path(path).suffix.lower() != ".npy":
            from .io import load_mesh

            surface = load_mesh(path)
            if surface.n_vertices == values.size:
                positions = surface.positions
            break
    names = (Path(reference).name, Path(candidate).name)
    report = compare_ao(a, b, positions=positions, threshold=threshold, worst=worst, names=names)
    if json_path is not None:
        with atomic_write(json_path) as tmp:
            tmp.write_text(report.to_json() + "\n")
    if plot_path is not None:
        plot_compare(a, b, plot_path, names=names)
    if render_path is not None:
        render_comparison(reference, candidate, render_path, up=up)
    return report


def sweep_file(
    source: str | Path,
    out_dir: str | Path,
    *,
    reference_rays: int = 4096,
    seed: int = 0,
    threads: int | None = None,
    repeats: int = 1,
    methods: Sequence[str] | None = None,
    fields: bool = True,
    up: str | None = None,
    plot: bool = True,
    progress: Progress | None = None,
    on_row=None,
    lights: Sequence = (),
    scene_lights: bool = True,
):
    """Bake ``source`` over the default grid of settings and score each against a
    high-ray Embree reference; write ``sweep.csv``, ``sweep.json`` and ``pareto.png``.

    With ``fields``, the mesh is also used as a rigid occluder resting on a ground grid:
    AO fields of several resolutions are fitted (their time is the fit) and the AO they
    cast on the ground is scored against Embree AO of the same scene (rows "field").

    The reference is cached in ``out_dir`` under a name keyed by the mesh's content,
    ``reference_rays`` and ``seed``, so repeated sweeps skip it.

    A lit scene (its own lights and emitters unless ``scene_lights=False``, plus
    ``lights``: ``--light`` specs) also gets irradiance rows (``quantity`` "irradiance",
    :func:`_light_sweep`) and ``pareto_irradiance.png``; a scene without light sweeps
    AO alone.

    Returns
    -------
    rows : list of aobake.tools.sweep.SweepRow
    """
    from .io import atomic_write
    from .tools import sweep

    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise OutputError(f"{output_name(out_dir)}: exists and is not a directory; sweep writes a directory")
    # the directory may exist (the reference cache lives there); its parent must
    check_output_dir(out_dir / "sweep.csv" if out_dir.is_dir() else out_dir)
    if plot:
        from .tools.plot import pyplot

        pyplot()  # matplotlib is checked before the work, not after it
    surface = as_surface(source)
    from . import lighting

    # read (and check) the light before any work; the plan is the reference method's
    light = lighting.prepare(source, surface, "embree", {}, lights=lights, scene_lights=scene_lights)
    try:
        out_dir.mkdir(exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{output_name(out_dir)}: cannot create the directory ({exc.strerror or exc})") from None
    key = sweep_key(surface)
    cache = out_dir / f"reference_{key}_rays{reference_rays}_seed{seed}.npy"
    reference = _cached_reference(cache, surface.n_vertices)
    if reference is None:
        from .methods.embree import embree_ao

        reference = embree_ao(surface, n_rays=reference_rays, seed=seed + 1, threads=threads, progress=progress).ao
        with atomic_write(cache) as tmp:
            np.save(tmp, reference)

    def compute(method, options):
        options.setdefault("threads", threads)
        if method == "embree":
            options.setdefault("seed", seed)
        ao, rays, *_ = _compute(surface, method, options, None)
        return ao, rays

    grid = sweep.default_grid(methods or METHODS)
    rows = sweep.run_sweep(compute, reference, grid, repeats=repeats, on_row=on_row)
    if fields:  # a different scene (the ground under the mesh): its own Pareto front
        up = up or surface.metadata.get("up_axis") or DEFAULT_UP_AXIS
        rows = rows + _field_sweep(surface, out_dir, key, up, reference_rays, seed, threads, repeats, on_row)
    lit_rows, lit_meta = [], {}
    if light is not None and light.lit:
        lit_rows, lit_meta = _light_sweep(
            surface, light, methods or METHODS, out_dir, key, reference_rays, seed, threads, repeats, on_row, progress
        )
    meta = {
        "source": Path(str(source)).name,
        "n_vertices": surface.n_vertices,
        "reference": f"embree, {reference_rays} rays, seed {seed + 1}",
        **lit_meta,
        "threads": threads,
        "version": __version__,
    }
    with atomic_write(out_dir / "sweep.csv") as tmp:
        tmp.write_text(sweep.to_csv(rows + lit_rows))
    with atomic_write(out_dir / "sweep.json") as tmp:
        tmp.write_text(sweep.to_json(rows + lit_rows, meta) + "\n")
    title = f"{meta['source']} ({surface.n_vertices} vertices)"
    if plot:
        sweep.plot_sweep(rows, out_dir / "pareto.png", title=title)
        if lit_rows:
            sweep.plot_sweep(
                lit_rows,
                out_dir / "pareto_irradiance.png",
                title=f"{title}: irradiance",
                ylabel="relative RMSE of irradiance against the reference",
                front_name="irradiance",
            )
    return rows + lit_rows


def sweep_key(surface: Surface) -> str:
    """The content key of a sweep's cached references (16 hex digits of the mesh's hash)."""
    import hashlib

    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(surface.positions).tobytes())
    digest.update(np.ascontiguousarray(surface.faces).tobytes())
    digest.update(np.ascontiguousarray(surface.normals).tobytes())
    return digest.hexdigest()[:16]


def light_key(light) -> str:
    """The content key of a lit scene's light (16 hex digits): its lights, the faces'
    albedo and emission and the effects planned, so another light is another reference."""
    import dataclasses
    import hashlib

    digest = hashlib.sha256()
    for item in light.shading.lights:
        for f in dataclasses.fields(item):
            value = getattr(item, f.name)
            if isinstance(value, np.ndarray):
                digest.update(np.ascontiguousarray(value, dtype=np.float64).tobytes())
            else:
                digest.update(repr(value).encode())
    digest.update(np.ascontiguousarray(light.shading.face_albedo, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(light.shading.face_emission, dtype=np.float64).tobytes())
    digest.update(",".join(light.plan.effects).encode())
    return digest.hexdigest()[:16]


def _light_sweep(surface, light, methods, out_dir, key, reference_rays, seed, threads, repeats, on_row, progress):
    """A lit scene's irradiance rows and their meta: each method of
    :func:`aobake.tools.sweep.light_grid` timed (the light alone, not the AO) and scored
    against Embree's irradiance at ``reference_rays`` samples per area light and 4x as
    many paths (seed + 1, cached in ``out_dir``), at the default bounces. Bunnell's rows
    are skipped with a warning on a mesh above its vertex limit."""
    import warnings

    from .io import atomic_write
    from .methods import LIGHTING, make_options, run_light
    from .tools import sweep

    indirect = "indirect" in light.plan.effects
    shading = light.shading
    paths = 4 * reference_rays
    name = f"reference_irradiance_{key}_{light_key(light)}_samples{reference_rays}_paths{paths}_seed{seed}.npy"
    cache = out_dir / name
    n = surface.n_vertices
    reference = _cached_reference(cache, 3 * n, upper=math.inf)
    if reference is None:
        options = {"light_samples": reference_rays, "indirect_rays": paths, "seed": seed + 1, "threads": threads}
        result = run_light("embree", surface, shading, options, progress, indirect=indirect)
        reference = (result.direct + result.indirect).ravel()
        with atomic_write(cache) as tmp:
            np.save(tmp, reference)
    reference = reference.reshape(n, 3)
    meta = {"irradiance_reference": f"embree, {reference_rays} samples, {paths} paths, seed {seed + 1}"}
    scale = float(np.sqrt(np.mean(reference**2)))  # the reference's RMS: errors are relative to it
    if not scale > 0:
        warnings.warn(
            f"{Path(str(surface.source)).name}: no irradiance rows: the reference irradiance is 0 at every vertex",
            stacklevel=2,
        )
        return [], meta
    methods = [m for m in methods if m in LIGHTING]
    if "bunnell" in methods:
        from .methods.bunnell import light as disk

        limit = getattr(disk, "MAX_VERTICES", None)
        if limit is not None and n > limit:
            warnings.warn(
                f"{Path(str(surface.source)).name}: {n:,} vertices: no bunnell irradiance rows "
                f"(--method bunnell lights at most {limit:,})",
                stacklevel=2,
            )
            methods.remove("bunnell")

    def compute(method, options):
        if method == "embree":
            options = {**options, "seed": seed, "threads": threads}
            result = run_light("embree", surface, shading, options, indirect=indirect)
        else:
            from .methods.bunnell.light import disk_light

            opts = make_options("bunnell", {"threads": threads})
            result = disk_light(surface, shading, opts, bounces=opts.bounces if indirect else 0, **options)
        return (result.direct + result.indirect) / scale, result.n_shadow_rays + result.n_bounce_rays

    grid = sweep.light_grid(methods)
    rows = sweep.run_sweep(compute, reference / scale, grid, repeats=repeats, on_row=on_row, quantity="irradiance")
    return rows, meta


def _cached_reference(cache: Path, n: int, upper: float = 1.0) -> np.ndarray | None:
    """A sweep's cached reference (``ao``; irradiance flattened, ``upper`` inf), or None
    when there is none yet; a cache that is not ``n`` finite values in [0, ``upper``] (or
    holds pickled data) is an :class:`InputError`."""
    if not cache.exists():
        return None
    from .io import read_bake

    values = read_bake(cache)  # a 1-D float .npy, pickles refused
    if values.shape != (n,) or not np.isfinite(values).all() or values.min() < 0 or values.max() > upper:
        bounds = "[0, 1]" if upper == 1 else ">= 0"
        raise InputError(
            cache,
            f"not a reference of {n} finite values {'in ' if upper == 1 else ''}{bounds}; delete it to recompute",
        )
    return values


def plan_file(
    source: str | Path,
    *,
    method: str = "embree",
    effects: str | Sequence[str] = "auto",
    lights: Sequence = (),
    scene_lights: bool = True,
    time: float | None = None,
    **options,
):
    """What ``aobake bake`` of ``source`` with these settings would compute, and why:
    ``(surface, shading, plan)`` (:func:`aobake.lighting.plan_for`). Reads the file;
    computes nothing."""
    from . import lighting

    surface = as_surface(source, time)
    shading = lighting.read(source, surface, lights=lights, scene_lights=scene_lights)
    return surface, shading, lighting.plan_for(surface, shading, method, options, lighting.parse_effects(effects))


def preview_file(
    bake: str | Path,
    output: str | Path,
    *,
    size: int = 640,
    up: str | None = None,
    view: str = "iso",
    azimuth: float | None = None,
    elevation: float | None = None,
    show: str = "ao",
) -> None:
    """Render a bake (a mesh file carrying ``ao``: PLY, USD or glTF) to a PNG, AO as grey;
    ``show="color"``: its vertex colours (the lit colour of ``--color``) instead."""
    from .io import load_mesh, read_bake, read_colours
    from .tools.preview import preview_png, write_png

    if Path(output).suffix.lower() != ".png":
        raise FormatError(f"{Path(output).name}: previews are written as PNG; use a .png suffix")
    check_output_dir(output)
    surface = load_mesh(bake)
    if show == "color":
        values = read_colours(bake, n_vertices=surface.n_vertices)
    else:
        values = read_bake(bake, n_vertices=surface.n_vertices)
    up = up or surface.metadata.get("up_axis") or DEFAULT_UP_AXIS
    png = preview_png(
        surface.positions, surface.faces, values, size=size, up=up, view=view, azimuth=azimuth, elevation=elevation
    )
    write_png(output, png)


def render_comparison(reference, candidate, output, *, size: int = 480, up: str | None = None, view: str = "iso"):
    """Side-by-side PNG of two bakes of one mesh and their difference (blue: candidate
    darker, red: lighter; full scale = the largest |difference|)."""
    from .io import load_mesh, read_bake
    from .tools.preview import error_colours, grey, render_values, write_png

    mesh_path = next((p for p in (reference, candidate) if Path(p).suffix.lower() != ".npy"), None)
    if mesh_path is None:
        raise FormatError(f"{Path(output).name}: rendering needs at least one bake that is a mesh (PLY, USD or glTF)")
    surface = load_mesh(mesh_path)
    a = read_bake(reference, n_vertices=surface.n_vertices)
    b = read_bake(candidate, n_vertices=surface.n_vertices)
    up = up or surface.metadata.get("up_axis") or DEFAULT_UP_AXIS
    kw = dict(size=size, up=up, view=view)
    ia = render_values(surface.positions, surface.faces, a, **kw)
    ib = render_values(surface.positions, surface.faces, b, **kw)
    diff = render_values(surface.positions, surface.faces, b - a, **kw)
    limit = float(np.nanmax(np.abs(diff))) if np.isfinite(diff).any() else 1.0
    gap = np.ones((size, 8, 3))
    write_png(output, np.concatenate([grey(ia), gap, grey(ib), gap, error_colours(diff, limit)], axis=1))


# --------------------------------------------------------------------------------------
# ambient occlusion fields


@dataclass(frozen=True)
class FieldReport:
    """What :func:`fit_field_file` did, for the one-line summary and for scripts.

    Attributes
    ----------
    source, output : str
    field : AOField
    seconds : float
        Fit time (loading, writing and compiling kernels excluded).
    n_bytes : int
        Size of the written file.
    compile_seconds : float
        Time numba spent compiling kernels (a cold cache: the first run).
    """

    source: str
    output: str
    field: Any
    seconds: float
    n_bytes: int
    compile_seconds: float = 0.0

    def summary(self) -> str:
        """One line: layout, sampler, time, fit residuals, size."""
        f = self.field
        p = f.params
        quality = f"{p.get('raster_size')} px" if p.get("sampler") == "raster" else f"{p.get('rays')} rays"
        return (
            f"{self.source}: field {f.resolution}x{f.resolution}x6, {p.get('radial_samples')} radial samples, "
            f"{f.model} model, {p.get('sampler')} ({quality}) in {self.seconds:.2f} s; "
            f"residuals Omega {f.omega_rms:.4f} sr, Y {f.y_rms_degrees:.2f} deg; "
            f"r_far {f.r_far:.4g}; {self.n_bytes / 1024:.0f} KB{compile_note(self.compile_seconds)}"
            f" -> {self.output}"
        )


def fit_field_file(
    source: str | Path,
    output: str | Path,
    *,
    progress: Progress | None = None,
    **options,
) -> FieldReport:
    """Load an occluder, fit its ambient occlusion field, write ``output`` (.npz) atomically.

    The suffix and directory are checked before loading or fitting. ``options`` go to
    :func:`aobake.methods.fields.fit_field`: the fields of
    :class:`~aobake.methods.fields.FieldOptions`.

    Returns
    -------
    FieldReport
    """
    from .methods.fields import fit_field, save_field

    output = Path(output)
    if output.suffix.lower() != ".npz":
        raise FormatError(f"{output.name}: a field is written as .npz, got {output.suffix or '(no suffix)'!r}")
    check_output_dir(output)
    surface = as_surface(source)
    with CompileWatch() as watch:  # the fit's time excludes compiling kernels
        result = fit_field(surface, progress=progress, **options)
    save_field(result, output)
    return FieldReport(
        source=Path(str(source)).name,
        output=str(output),
        field=result,
        seconds=max(result.seconds - watch.seconds, 0.0),
        n_bytes=output.stat().st_size,
        compile_seconds=watch.seconds,
    )


def _load_fields(fields) -> list:
    """[(AOField, transform or None, name)] from AOFields, paths, or (item, transform)."""
    if not fields:
        return []  # a bake without fields never imports the field method (and its kernels)
    from .methods.fields import AOField, load_field, rigid_transform

    out = []
    for item in fields or ():
        transform = None
        if isinstance(item, tuple):
            item, transform = item
        if transform is not None and np.ndim(transform) == 1:
            values = [float(v) for v in transform]
            if len(values) not in (3, 6):
                raise ValueError(f"a field placement has 3 or 6 numbers (tx, ty, tz[, rx, ry, rz]), got {len(values)}")
            transform = rigid_transform(values[:3], values[3:] if len(values) == 6 else (0.0, 0.0, 0.0))
        f = item if isinstance(item, AOField) else load_field(item)
        name = f.occluder_name if isinstance(item, AOField) else Path(item).name
        out.append((f, transform, name))
    return out


def _apply_fields(surface: Surface, ao: AOArray, placed: list, threads) -> tuple[AOArray, tuple]:
    """``ao`` times every field's 1 - A_k at the surface's vertices, and the skips."""
    from .methods.fields import fields_ao

    result = fields_ao(
        [f for f, _, _ in placed],
        surface.positions,
        surface.normals,
        transforms=[t for _, t, _ in placed],
        threads=threads,
    )
    return np.asarray(ao) * result.ao, result.skipped


def _field_sweep(surface, out_dir, key, up_axis, reference_rays, seed, threads, repeats, on_row):
    """Rows for AO fields: ``surface`` as a rigid occluder on a ground grid (3 bounding
    radii each way, at its lowest point along ``up_axis``), scored
    on the ground vertices against Embree AO of occluder + ground."""
    from .io import atomic_write
    from .mesh import surface_from_arrays
    from .methods.embree import embree_ao
    from .methods.fields import field_ao, fit_field
    from .tools import sweep

    up = 1 if up_axis.upper() == "Y" else 2
    lo, hi = surface.positions.min(axis=0), surface.positions.max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    cells = 64
    t = np.linspace(-1.5 * radius, 1.5 * radius, cells + 1)
    u, v = np.meshgrid(t, t, indexing="ij")
    axes = [a for a in range(3) if a != up]
    ground = np.zeros((u.size, 3))
    ground[:, axes[0]] = centre[axes[0]] + u.ravel()
    ground[:, axes[1]] = centre[axes[1]] + v.ravel()
    ground[:, up] = lo[up]
    i, j = np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij")
    a = (i * (cells + 1) + j).ravel()
    quads = np.c_[a, a + cells + 1, a + cells + 2, a + 1]
    tri = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    normal = np.zeros(3)
    normal[up] = 1.0
    g_normals = np.tile(normal, (len(ground), 1))
    # orient the triangles to face up
    e = np.cross(ground[tri[:, 1]] - ground[tri[:, 0]], ground[tri[:, 2]] - ground[tri[:, 0]])
    if (e @ normal).mean() < 0:
        tri = tri[:, ::-1]
    n = surface.n_vertices
    scene = surface_from_arrays(
        np.vstack([surface.positions, ground]),
        np.vstack([surface.faces, tri + n]),
        np.vstack([surface.normals, g_normals]),
    )
    cache = out_dir / f"reference_ground{up_axis}_{key}_rays{reference_rays}_seed{seed}.npy"
    reference = _cached_reference(cache, len(ground))
    if reference is None:
        reference = embree_ao(scene, n_rays=reference_rays, seed=seed + 1, threads=threads).ao[n:]
        with atomic_write(cache) as tmp:
            np.save(tmp, reference)

    def compute(method, options):
        f = fit_field(surface, seed=seed, threads=threads, **options)
        return field_ao(f, ground, g_normals, threads=threads), 0

    return sweep.run_sweep(compute, reference, sweep.field_grid(), repeats=repeats, on_row=on_row)


# --------------------------------------------------------------------------------------
# the first run


@dataclass(frozen=True)
class WarmUpReport:
    """What :func:`warm_up` did.

    Attributes
    ----------
    steps : tuple of str
        The commands run, in order.
    seconds : float
        Wall time of the whole warm-up.
    compile_seconds : float
        Of it, numba compiling kernels (0 when the cache was already warm).
    kernels : int
        Kernel specialisations compiled.
    """

    steps: tuple
    seconds: float
    compile_seconds: float
    kernels: int

    def summary(self) -> str:
        """One line: what ran, how long, how much of it was compiling."""
        done = "compiled" if self.kernels else "already compiled (cache warm)"
        return (
            f"warm-up: {', '.join(self.steps)}: kernels {done}; {self.seconds:.1f} s"
            + (f", of it {self.compile_seconds:.1f} s compiling {self.kernels} kernels" if self.kernels else "")
        )


def warm_up_scene():
    """The warm-up's built-in scene: a unit cube resting on an 8 x 8 grid (+Y up), with
    contacts, a crevice and open ground: (positions, faces) in float64 / int64."""
    cube_v, cube_f = _unit_cube()
    cube_p = cube_v + [0.0, 0.5, 0.0]
    t = np.linspace(-2.0, 2.0, 9)
    x, z = np.meshgrid(t, t, indexing="ij")
    grid_p = np.c_[x.ravel(), np.zeros(x.size), z.ravel()]
    i, j = np.meshgrid(np.arange(8), np.arange(8), indexing="ij")
    a = (i * 9 + j).ravel()
    grid_f = np.vstack([np.c_[a, a + 1, a + 10], np.c_[a, a + 10, a + 9]])  # facing +Y
    positions = np.vstack([cube_p, grid_p])
    faces = np.vstack([cube_f, grid_f + len(cube_p)])
    return positions, faces


def _write_lit_usda(path: Path, positions, faces) -> None:
    """A minimal USD stage of a triangle mesh lit by a RectLight 3 units above it, facing
    down (the warm-up's input for the disk method's area-light passes)."""
    pts = ", ".join(f"({float(x)!r}, {float(y)!r}, {float(z)!r})" for x, y, z in np.asarray(positions, dtype=float))
    idx = ", ".join(str(int(i)) for i in np.asarray(faces).ravel())
    path.write_text(
        '#usda 1.0\n(\n    upAxis = "Y"\n)\n\n'
        'def Mesh "scene"\n{\n'
        f"    int[] faceVertexCounts = [{', '.join(['3'] * len(faces))}]\n"
        f"    int[] faceVertexIndices = [{idx}]\n"
        f"    point3f[] points = [{pts}]\n"
        "}\n\n"
        'def RectLight "light"\n{\n'
        "    float inputs:width = 1\n    float inputs:height = 1\n    float inputs:intensity = 10\n"
        "    float3 xformOp:rotateXYZ = (-90, 0, 0)\n    double3 xformOp:translate = (0, 3, 0)\n"
        '    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]\n'
        "}\n"
    )


def _unit_cube():
    """A unit cube centred at the origin: 8 corners (bit k of the index: axis k at +0.5)
    and 12 outward-facing triangles."""
    corners = np.array([[(k >> a & 1) - 0.5 for a in range(3)] for k in range(8)], dtype=np.float64)
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    faces = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], dtype=np.int64)
    return corners, faces


def _write_plain_ply(path: Path, positions, faces) -> None:
    """A minimal ASCII PLY of a triangle mesh (the warm-up's inputs)."""
    lines = ["ply", "format ascii 1.0", f"element vertex {len(positions)}", "property double x",
             "property double y", "property double z", f"element face {len(faces)}",
             "property list uchar int vertex_indices", "end_header"]  # fmt: skip
    lines += [" ".join(repr(float(c)) for c in p) for p in positions]
    lines += ["3 " + " ".join(str(int(i)) for i in f) for f in faces]
    path.write_text("\n".join(lines) + "\n")


# Options that run kernels a default bake does not: the disk method's later passes (and
# its uniform measure) use a second tree-pass kernel (kernels.treepass.hierarchy_pass).
_WARM_UP_VARIANTS = {"bunnell": (("--passes 2", {"passes": 2}),)}


def warm_up(progress: Progress | None = None) -> WarmUpReport:
    """Compile what the commands need (numba caches it on disk), so that a user's first
    ``aobake bake`` / ``field`` / ``preview`` does not: every method, a small field fit and
    its use in a bake, and a preview, all through the same file paths the commands take,
    on a tiny built-in scene (:func:`warm_up_scene`) in a temporary directory that is
    removed afterwards. Seconds on a warm cache; a cold one takes what compiling takes."""
    import tempfile

    steps = []
    with CompileWatch() as watch, tempfile.TemporaryDirectory(prefix="aobake-warm-up-") as tmp:
        t0 = perf_counter()
        d = Path(tmp)
        positions, faces = warm_up_scene()
        _write_plain_ply(d / "scene.ply", positions, faces)
        _write_plain_ply(d / "cube.ply", *_unit_cube())
        for method in METHODS:
            bake_file(d / "scene.ply", [d / f"{method}.ply", d / f"{method}.usda"], method=method,
                      progress=progress)
            steps.append(f"bake --method {method}")
            for flags, extra in _WARM_UP_VARIANTS.get(method, ()):
                bake_file(d / "scene.ply", d / f"{method}_variant.ply", method=method, progress=progress, **extra)
                steps.append(f"bake --method {method} {flags}")
        bake_file(d / "scene.ply", d / "lit.ply", method=METHODS[0], lights=("point:0,3,0:10",), color=True,
                  n_rays=4, light_samples=2, indirect_rays=2, progress=progress)  # the light kernels
        steps.append("bake --light")
        _write_lit_usda(d / "lit.usda", positions, faces)
        with warnings.catch_warnings():  # its scene's warnings (negative light) are not the user's
            warnings.simplefilter("ignore")
            bake_file(d / "lit.usda", d / "lit_bunnell.ply", method="bunnell", progress=progress)  # the light passes
        steps.append("bake --method bunnell (lit)")
        fit_field_file(d / "cube.ply", d / "cube.npz", progress=progress, resolution=4, radial_samples=8)
        steps.append("field")
        grid = d / "grid.ply"
        _write_plain_ply(grid, positions[8:], faces[12:] - 8)
        bake_file(grid, d / "grid_field.ply", method=METHODS[0], fields=[(d / "cube.npz", (0.0, 0.5, 0.0))],
                  progress=progress)
        steps.append("bake --field")
        preview_file(d / f"{METHODS[0]}.ply", d / "preview.png", size=16)
        steps.append("preview")
        seconds = perf_counter() - t0
    return WarmUpReport(steps=tuple(steps), seconds=seconds, compile_seconds=watch.seconds, kernels=watch.count)
