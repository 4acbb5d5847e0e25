"""Which effects a scene calls for, why, which receivers each light can reach, and the cost.

``aobake plan`` prints a :class:`Plan`; ``aobake bake`` computes what it lists and says so
in its summary line. The reach test here is plain numpy, written apart from the light
transport's own culling (:mod:`aobake.methods.embree.light`), and the tests check that
the two agree receiver by receiver.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .constants import EFFECTS
from .mesh import Surface
from .shading import Light, Shading


@dataclass(frozen=True)
class LightPlan:
    """One light's part in a bake.

    Attributes
    ----------
    light : Light
    reach : int
        Receivers it can light (in front of their tangent plane, inside its cone and range).
    shadow_rays : int
        Shadow rays it will cast for direct light (0: shadows off, or nothing in reach).
    why_skipped : str
        Why it adds nothing ("" when it is used): black, behind every receiver...
    """

    light: Light
    reach: int
    shadow_rays: int
    why_skipped: str = ""


@dataclass(frozen=True)
class Plan:
    """What a bake computes and why (``aobake plan``; the bake's summary line).

    Attributes
    ----------
    effects : tuple of str
        Subset of :data:`EFFECTS`, in that order.
    reasons : dict
        effect -> why it is computed, or why not (for every effect in :data:`EFFECTS`).
    lights : tuple of LightPlan
    emitting_faces : int
        Triangles with emission above zero (area lights made of the mesh itself).
    rays : dict
        Expected rays by kind: ``"ao"``, ``"shadow"`` (direct light), ``"bounce"``
        (indirect paths, each hit's shadow rays included).
    """

    effects: tuple[str, ...]
    reasons: dict
    lights: tuple[LightPlan, ...] = ()
    emitting_faces: int = 0
    rays: dict = field(default_factory=dict)

    @property
    def skipped(self) -> tuple[LightPlan, ...]:
        """Lights that add nothing to this bake."""
        return tuple(p for p in self.lights if p.why_skipped)

    def summary(self) -> str:
        """One line: "effects ao, direct (2 lights), indirect (1 bounce); skipped light /x (behind ...)"."""
        text = "effects " + ", ".join(self.effects)
        skipped = self.skipped
        if skipped:
            text += "; skipped " + ", ".join(f"{p.light.name} ({p.why_skipped})" for p in skipped)
        return text

    def report(self) -> str:
        """Several lines for ``aobake plan``: each effect and why, each light and its reach,
        the expected rays."""
        lines = []
        for effect in EFFECTS:
            mark = "yes" if effect in self.effects else "no "
            lines.append(f"{mark} {effect:<9} {self.reasons[effect]}")
        for p in self.lights:
            what = f"skipped: {p.why_skipped}" if p.why_skipped else f"{p.reach} receivers in reach, {p.shadow_rays} shadow rays"
            lines.append(f"    light {p.light.name} ({p.light.kind}): {what}")
        if self.emitting_faces:
            lines.append(f"    {self.emitting_faces} emitting triangles (area lights that also occlude)")
        if self.rays:
            total = sum(self.rays.values())
            parts = ", ".join(f"{k} {v:,}" for k, v in self.rays.items() if v)
            lines.append(f"expected rays: {total:,} ({parts})" if total else "expected rays: none")
        return "\n".join(lines)


def reach(light: Light, positions: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(n,) bool: receivers ``light`` can light at all.

    A receiver (point x, unit normal n; a zero normal reaches nothing) is in reach when
    some of the light lies strictly in front of its tangent plane, it is on an area
    light's emitting side, inside a spot's outer cone and within ``range``.
    """
    x = np.asarray(positions, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    has_normal = np.einsum("ij,ij->i", n, n) > 0
    if light.is_black:
        return np.zeros(len(x), dtype=bool)
    kind = light.kind
    if kind == "dome":
        return has_normal
    if kind == "distant":
        return has_normal & (n @ light.direction > -math.sin(0.5 * light.angle))
    to_light = light.position - x
    dist = np.sqrt(np.einsum("ij,ij->i", to_light, to_light))
    ok = has_normal & (dist < light.range)
    if kind in ("point", "spot"):
        ok &= np.einsum("ij,ij->i", n, to_light) > 0
        if kind == "spot":
            with np.errstate(invalid="ignore", divide="ignore"):
                cos_axis = -(to_light @ light.direction) / dist
            ok &= cos_axis > math.cos(light.cone_outer)
        return ok
    if kind == "sphere":
        return ok & (np.einsum("ij,ij->i", n, to_light) > -light.radius) & (dist > light.radius)
    # one-sided area lights: the receiver on the emitting side, some of the light in front
    ok &= (x - light.position) @ light.normal > 0
    if kind == "rect":
        corners = [light.position + su * light.u + sv * light.v for su in (-1, 1) for sv in (-1, 1)]
        front = np.zeros(len(x), dtype=bool)
        for c in corners:
            front |= np.einsum("ij,ij->i", n, c - x) > 0
        return ok & front
    # disk: its farthest point along n is the centre plus radius times n's in-plane part
    m = light.normal
    in_plane = n - np.outer(n @ m, m)
    extent = light.radius * np.sqrt(np.einsum("ij,ij->i", in_plane, in_plane))
    return ok & (np.einsum("ij,ij->i", n, to_light) + extent > 0)


def make_plan(
    surface: Surface,
    shading: Shading | None,
    *,
    effects: str | tuple[str, ...] = "auto",
    bounces: int = 1,
    ao_rays: int = 0,
    area_samples: int = 1,
    cone_samples: int = 1,
    indirect_rays: int = 0,
) -> Plan:
    """The effects ``surface`` under ``shading`` calls for, restricted to ``effects``.

    ``effects``: ``"auto"`` (what the scene calls for: AO always; direct light when a
    light or emitter adds light; indirect when, in addition, ``bounces`` > 0 and some
    albedo is above zero) or a tuple of names from :data:`EFFECTS` (only those, and
    only where the scene calls for them: asking for direct light in a scene without
    lights is an error, ``ValueError``). Ray counts assume ``ao_rays`` per vertex,
    ``area_samples`` shadow rays per area light and receiver, ``cone_samples`` for a
    distant light with an angle, and ``indirect_rays`` paths per vertex per bounce.
    """
    n = surface.n_vertices
    lit = shading is not None and shading.has_light
    reflects = shading is not None and shading.reflects
    reasons = {"ao": "always (the attribute ao)"}
    if lit:
        names = [light.name for light in shading.lights if not light.is_black]
        emitters = int(np.count_nonzero(np.any(shading.face_emission > 0, axis=1)))
        what = []
        if names:
            what.append(f"{len(names)} light{'s' if len(names) != 1 else ''}")
        if emitters:
            what.append(f"{emitters} emitting triangles")
        reasons["direct"] = "the scene has " + " and ".join(what)
    else:
        reasons["direct"] = "no lights or emitters in the scene"
    if not lit:
        reasons["indirect"] = "no light to bounce"
    elif bounces <= 0:
        reasons["indirect"] = "--bounces 0"
    elif not reflects:
        reasons["indirect"] = "every albedo is zero"
    else:
        reasons["indirect"] = f"{bounces} bounce{'s' if bounces != 1 else ''} off albedo above zero"
    called = ["ao"] + (["direct"] if lit else []) + (["indirect"] if lit and bounces > 0 and reflects else [])
    if effects == "auto":
        chosen = called
    else:
        asked = tuple(effects)
        unknown = [e for e in asked if e not in EFFECTS]
        if unknown:
            raise ValueError(f"unknown effect {unknown[0]!r}; choose from {', '.join(EFFECTS)} or auto")
        for e in asked:
            if e not in called:
                raise ValueError(f"--effects {e}: the scene does not call for it ({reasons[e]})")
        if "indirect" in asked and "direct" not in asked:
            raise ValueError("--effects indirect needs direct too (bounced light starts as direct light)")
        chosen = [e for e in EFFECTS if e in asked or e == "ao"]
        for e in EFFECTS:
            if e not in chosen and e in called:
                reasons[e] = "not asked for (--effects)"
    plans = []
    shadow_total = 0
    if shading is not None:
        for light in shading.lights:
            if light.is_black:
                plans.append(LightPlan(light, 0, 0, "black: intensity or colour zero"))
                continue
            k = int(np.count_nonzero(reach(light, surface.positions, surface.normals)))
            samples = area_samples if light.kind in ("sphere", "rect", "disk") else 1
            if light.kind == "distant" and light.angle > 0:
                samples = cone_samples
            if light.kind == "dome":
                samples = 0  # the AO rays are its shadow rays
            rays = k * samples if light.shadow else 0
            why = "" if k else "no receiver in reach (behind every tangent plane, outside its cone or range)"
            plans.append(LightPlan(light, k, rays, why))
            if "direct" in chosen:
                shadow_total += rays
    emitting = 0 if shading is None else int(np.count_nonzero(np.any(shading.face_emission > 0, axis=1)))
    if "direct" in chosen and emitting:
        shadow_total += n * area_samples
    rays = {"ao": n * ao_rays, "shadow": shadow_total}
    if "indirect" in chosen:
        per_hit = 1 + sum(1 for p in plans if not p.why_skipped and p.light.shadow) + (1 if emitting else 0)
        rays["bounce"] = n * indirect_rays * bounces * per_hit
    return Plan(tuple(chosen), reasons, tuple(plans), emitting, rays)
