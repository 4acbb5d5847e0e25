"""Options of the ray-traced reference (light: no numpy, read by ``aobake --help``)."""

from __future__ import annotations

from dataclasses import dataclass

from ...options import (
    bounces_option,
    max_distance_option,
    measure_option,
    option,
    seed_option,
    threads_option,
    validate,
)

#: Most rays per vertex: the Sobol index of a ray is a 32-bit integer.
MAX_RAYS = 2**32


# The light fields, spelled once: EmbreeOptions carries them for the CLI (`bake` of a lit
# scene), LightOptions for :func:`aobake.methods.embree.light.irradiance`.
def _light_samples():
    return option(64, "Shadow rays per area light and vertex (lit scenes).", kind=int, low=1, high=MAX_RAYS, flag="light-samples")


def _bias():
    return option(None, "Ray origin offset along the normal (mesh units).", kind=float, low=0,
                  none="from float precision and edge length")  # fmt: skip


def _indirect_rays():
    return option(
        256,
        "Indirect paths per vertex (lit scenes; each bounce adds one ray per path).",
        kind=int, low=1, high=MAX_RAYS, flag="indirect-rays",
    )  # fmt: skip


@dataclass(frozen=True)
class EmbreeOptions:
    """What a user chooses for :func:`aobake.methods.embree.embree_ao`.

    Attributes
    ----------
    n_rays : int
        Rays per vertex (the most, with ``tolerance``); ``--rays``.
    measure : {"cosine", "uniform"}
    max_distance : float or None
        Rays stop at this distance (mesh units); None = unbounded.
    bias : float or None
        Ray-origin offset along the normal in mesh units; None = from float precision
        and the local edge length (:func:`aobake.contacts.ray_offsets`).
    tolerance : float or None
        Adaptive sampling: stop a vertex once its 95% interval half-width is below this
        (for light: below this fraction of its irradiance).
    bent_normals : bool
        Also estimate the bent normal per vertex (``EmbreeAO.bent_normals``, written
        as the attribute ``bentNormal``) from the same rays.
    light_samples, bounces, indirect_rays : int
        A lit scene's light (:class:`LightOptions` ``n_samples``, ``bounces``,
        ``n_indirect``); unused where the scene has no light.
    seed : int
        Key of the per-vertex Owen-scrambled Sobol directions.
    threads : int or None
        Worker threads (default: all cores); the result does not depend on it.
    """

    n_rays: int = option(256, "Rays per vertex (the most, with --tolerance).", kind=int, low=1, high=MAX_RAYS, flag="rays")
    measure: str = measure_option()
    max_distance: float | None = max_distance_option()
    bias: float | None = _bias()
    tolerance: float | None = option(
        None,
        "Adaptive: stop a vertex once its 95% interval half-width is below this (light: this fraction of its irradiance).",
        kind=float,
        low=0,
        low_open=True,
        none="off",
    )
    bent_normals: bool = option(
        False,
        "Also write bentNormal: the mean unoccluded direction per vertex (unit, world space).",
        kind=bool,
    )
    light_samples: int = _light_samples()
    bounces: int = bounces_option()
    indirect_rays: int = _indirect_rays()
    seed: int = seed_option()
    threads: int | None = threads_option()

    def __post_init__(self):
        validate(self)

    def light(self, **changes) -> LightOptions:
        """The :class:`LightOptions` these options stand for (``changes`` override them)."""
        fields = dict(
            n_samples=self.light_samples, bounces=self.bounces, n_indirect=self.indirect_rays,
            tolerance=self.tolerance, max_distance=self.max_distance, bias=self.bias,
            seed=self.seed, threads=self.threads,
        )  # fmt: skip
        fields.update(changes)
        return LightOptions(**fields)


OPTIONS = EmbreeOptions


@dataclass(frozen=True)
class LightOptions:
    """What a user chooses for :func:`aobake.methods.embree.light.irradiance`.

    Attributes
    ----------
    n_samples : int
        Shadow rays per area light (rect, disk, sphere, the emitting triangles together,
        a distant light with an angle) and receiver; point, spot and sharp distant
        lights take one.
    bounces : int
        Indirect bounces K (0 = direct light only).
    n_indirect : int
        Cosine-weighted paths per vertex (they also carry a dome's light).
    tolerance : float or None
        Adaptive: stop a vertex once its 95% half-width is below this fraction of its
        irradiance (per channel, the largest).
    max_distance, bias, seed, threads
        As for :class:`EmbreeOptions`.
    """

    n_samples: int = _light_samples()
    bounces: int = bounces_option()
    n_indirect: int = _indirect_rays()
    tolerance: float | None = option(
        None,
        "Adaptive: stop a vertex once its 95% half-width is below this fraction of its irradiance.",
        kind=float,
        low=0,
        low_open=True,
        none="off",
    )
    max_distance: float | None = max_distance_option()
    bias: float | None = _bias()
    seed: int = seed_option()
    threads: int | None = threads_option()

    def __post_init__(self):
        validate(self)
