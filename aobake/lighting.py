"""A bake's light: read the scene's lights and materials, plan the effects it calls for,
compute them beside the AO, and say what was done.

:mod:`aobake.pipeline` calls :func:`prepare` once the surface is loaded and
:func:`compute` beside each AO computation; a scene without lights or emitters gets no
job, so it bakes exactly the AO it baked before light existed.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from .constants import EFFECTS
from .errors import InputError
from .mesh import Surface
from .plan import Plan, make_plan
from .shading import Shading

#: Names of the attributes a lit bake writes (``irradiance`` always; the terms with
#: ``split``): linear RGB, the incident irradiance on the side the normal points to.
IRRADIANCE = "irradiance"
TERMS = ("irradiance_direct", "irradiance_indirect")


@dataclass(frozen=True)
class LightJob:
    """What a bake computes besides AO, and from what.

    Attributes
    ----------
    shading : Shading
        The scene's lights, albedo and emission (:func:`aobake.io.lights.read_shading`).
    plan : Plan
        The effects computed (``"direct"`` in ``plan.effects``: there is light to compute).
    split : bool
        Also write ``irradiance_direct`` and ``irradiance_indirect``.
    exposure : float
        Stops applied to the lit colour ``--color`` writes.
    """

    shading: Shading
    plan: Plan
    split: bool = False
    exposure: float = 0.0

    @property
    def lit(self) -> bool:
        return "direct" in self.plan.effects


@dataclass(frozen=True)
class LightTotals:
    """Rays and time the light took (summed into the bake's report)."""

    shadow_rays: int = 0
    path_rays: int = 0
    seconds: float = 0.0


def parse_effects(text: str | Sequence[str]) -> str | tuple[str, ...]:
    """``"auto"`` or a tuple of effect names from ``"ao,direct"`` (``ValueError`` naming an
    unknown one)."""
    if isinstance(text, str):
        if text.strip() == "auto":
            return "auto"
        names = tuple(t.strip() for t in text.split(",") if t.strip())
    else:
        names = tuple(text)
    for name in names:
        if name not in EFFECTS:
            raise ValueError(f"--effects: unknown effect {name!r}; give auto or a list of {', '.join(EFFECTS)}")
    if not names:
        raise ValueError("--effects: give auto or a list of " + ", ".join(EFFECTS))
    return names


def prepare(
    source: Any,
    surface: Surface,
    method: str,
    options: dict,
    *,
    effects: str | Sequence[str] = "auto",
    lights: Sequence = (),
    scene_lights: bool = True,
    split: bool = False,
    exposure: float = 0.0,
) -> LightJob | None:
    """The light job of a bake, or None when it computes AO only.

    Reads ``source``'s lights and materials (``scene_lights=False``: its materials only)
    and the ``lights`` given (``--light`` strings or :class:`~aobake.shading.Light`),
    then plans ``effects`` (:func:`aobake.plan.make_plan`). ``effects="ao"`` reads
    nothing. A method that computes no light (:data:`aobake.methods.LIGHTING`) bakes a
    lit scene's AO with a warning under ``"auto"``; an explicit light effect is then an
    error. The reader's notes become warnings.
    """
    from .methods import LIGHTING

    try:
        effects = parse_effects(effects)
    except ValueError as exc:
        raise InputError(surface.source, str(exc)) from None
    if effects == ("ao",):
        if lights:
            warnings.warn("--light is not used: --effects ao computes ambient occlusion only", stacklevel=2)
        return None
    if effects == "auto" and not lights and surface.metadata.get("format") == "PLY":
        return None  # a PLY has no lights and emits nothing: AO alone, no shading arrays made
    shading = read(source, surface, lights=lights, scene_lights=scene_lights)
    for note in shading.notes:
        warnings.warn(f"{Path(str(surface.source)).name}: {note}", stacklevel=2)
    if method not in LIGHTING:
        plan = plan_for(surface, shading, method, options, effects)
        if plan.reasons["direct"].startswith("the scene has"):
            warnings.warn(
                f"{Path(str(surface.source)).name}: the scene's light is not baked: {plan.reasons['indirect']}",
                stacklevel=2,
            )
        return None
    plan = plan_for(surface, shading, method, options, effects)
    if plan.effects == ("ao",):
        return None
    return LightJob(shading, plan, split, exposure)


def plan_for(surface: Surface, shading: Shading, method: str, options: dict, effects="auto") -> Plan:
    """:func:`aobake.plan.make_plan` with the ray counts of ``method``'s ``options``; a
    request the scene cannot meet is an InputError naming the file."""
    from .methods import LIGHTING, make_options

    opts = make_options(method, options)
    lit = method in LIGHTING
    if not lit:
        if effects != "auto" and tuple(effects) != ("ao",):
            raise InputError(
                surface.source,
                f"--effects {','.join(effects)}: --method {method} computes ambient occlusion only; light needs --method {LIGHTING[0]}",
            )
        plan = make_plan(surface, shading, effects="auto", bounces=0)
        if plan.effects == ("ao",):
            return plan
        why = f"--method {method} computes ambient occlusion only (light: --method {LIGHTING[0]})"
        reasons = {**plan.reasons, "direct": f"{plan.reasons['direct']}, but {why}", "indirect": why}
        lights = tuple(replace(p, shadow_rays=0) for p in plan.lights)
        return replace(plan, effects=("ao",), reasons=reasons, lights=lights, rays={})
    try:
        return make_plan(
            surface,
            shading,
            effects=effects,
            bounces=opts.bounces,
            ao_rays=getattr(opts, "n_rays", 0),
            # the disk method: one ray per point, spot or sharp distant light; none for
            # area lights, emitters and bounces (the transfer carries them)
            area_samples=getattr(opts, "light_samples", 0),
            cone_samples=getattr(opts, "light_samples", 1),
            indirect_rays=getattr(opts, "indirect_rays", 0),
        )
    except ValueError as exc:
        raise InputError(surface.source, str(exc)) from None


def read(source: Any, surface: Surface, *, lights: Sequence = (), scene_lights: bool = True) -> Shading:
    """The shading of ``surface``: read from ``source`` when it is a file (or a surface
    :func:`aobake.io.load_mesh` read from one: batch's --split ranges get those), else
    every surface 0.18 grey, lit by ``lights`` alone."""
    from .io.lights import parse_light_spec, read_shading
    from .shading import default_shading

    if not isinstance(source, (str, Path)) and source is surface and surface.metadata.get("path"):
        source = surface.metadata["path"]
    if isinstance(source, (str, Path)):
        return read_shading(source, surface, scene_lights=scene_lights, cli_lights=lights, dark_materials=False)
    parsed = [parse_light_spec(x, k) if isinstance(x, str) else x for k, x in enumerate(lights, 1)]
    return default_shading(surface.n_vertices, surface.n_faces, parsed)


def compute(
    job: LightJob, scene: Surface, method: str, options: dict, progress, *, faces=None, inverse=None, ground=None
):
    """Irradiance attributes of a bake (per input vertex) and its :class:`LightTotals`.

    ``scene``: the surface the AO was traced on; ``faces`` (bool per face of the input
    surface): the triangles it kept (``--occluders``); ``inverse``: a welded scene's
    vertex for each input vertex (``--weld``); ``ground``: the resolved ``--ground``
    plane (occludes and reflects, :data:`aobake.ground.ALBEDO`).
    """
    from .io.lights import welded_shading
    from .methods import run_light

    shading = job.shading
    if faces is not None:
        shading = replace(shading, face_albedo=shading.face_albedo[faces], face_emission=shading.face_emission[faces])
    if inverse is not None:
        shading = welded_shading(shading, inverse)
    result = run_light(
        method, scene, shading, options, progress, indirect="indirect" in job.plan.effects, ground=ground
    )
    direct, indirect = result.direct, result.indirect
    if inverse is not None:
        direct, indirect = direct[inverse], indirect[inverse]
    attributes = {IRRADIANCE: direct + indirect}
    if job.split:
        attributes.update(zip(TERMS, (direct, indirect), strict=True))
    return attributes, LightTotals(result.n_shadow_rays, result.n_bounce_rays, result.seconds)


def lit_colour(job: LightJob, irradiance: np.ndarray) -> np.ndarray:
    """(n, 3) linear RGB in [0, 1] that ``--color`` writes: albedo x irradiance / pi plus
    emission, times 2^exposure, clamped."""
    shading = job.shading
    radiance = shading.vertex_albedo * np.asarray(irradiance) / np.pi + shading.vertex_emission
    return np.clip(radiance * 2.0**job.exposure, 0.0, 1.0)


def custom_data(job: LightJob, options: dict, method: str) -> dict:
    """What a lit output records: the effects, the lights used and skipped, the settings."""
    from .methods import make_options

    opts = make_options(method, options)
    used = [p.light.name for p in job.plan.lights if not p.why_skipped]
    skipped = [p.light.name for p in job.plan.lights if p.why_skipped]
    out = {
        "effects": ", ".join(job.plan.effects),
        "lights": ", ".join(used) or "none",
        "albedo": job.shading.sources.get("albedo", ""),
    }
    if hasattr(opts, "light_samples"):
        out["light_samples"] = opts.light_samples
    if skipped:
        out["lights_skipped"] = ", ".join(skipped)
    if job.plan.emitting_faces:
        out["emitting_triangles"] = job.plan.emitting_faces
    if "indirect" in job.plan.effects:
        out["bounces"] = opts.bounces
        if hasattr(opts, "indirect_rays"):
            out["indirect_rays"] = opts.indirect_rays
    if job.exposure:
        out["exposure"] = job.exposure
    return out


def summary(job: LightJob, totals: LightTotals) -> str:
    """The light's part of the bake's summary line (its rays are in the bake's total)."""
    rays = totals.shadow_rays + totals.path_rays
    cost = f"{rays / 1e6:.3f} M of the rays" if rays else "no rays"
    return job.plan.summary() + f" ({cost} for light, {totals.seconds:.2f} s)"
