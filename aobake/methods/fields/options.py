"""Options of the AO-field method (light: no numpy, read by ``aobake field --help``)."""

from __future__ import annotations

from dataclasses import dataclass

from ...options import option, seed_option, threads_option, validate

#: How Omega and Y are measured at the sample points.
SAMPLERS = ("raster", "embree")
#: Radial models of Omega, in the order ``--help`` lists them.
MODELS = ("cap", "paper", "table")
#: Default r_far in bounding radii: a sphere of that radius seen from 8 radii subtends
#: 0.05 sr (A <= 1/64 for any normal), so the cut changes AO by at most ~0.016 and the
#: fade from r_near hides it.
R_FAR_FACTOR = 8.0


@dataclass(frozen=True)
class FieldOptions:
    """What a user chooses for :func:`aobake.methods.fields.fit_field`.

    Attributes
    ----------
    sampler : {"raster", "embree"}
        Omega and Y at the sample points: cube maps rasterized on the CPU
        (``raster_size`` texels per edge) or ``n_rays`` Embree rays over the sphere.
    resolution : int
        R, cube-map texels per face edge of the field (6 R^2 directions, plus a border).
        Beyond 16 the radial model, not the angular resolution, limits accuracy.
    radial_samples : int
        M >= 3 sample distances per texel, log-spaced from just outside the convex hull
        to r_far; fewer starve the contact region, more cost linearly.
    raster_size : int
        Cube-map edge of the raster sampler: 6 size^2 texels around each sample point.
        Larger mostly sharpens silhouettes, while the radial model limits the fit.
    n_rays : int
        Rays per sample point of the Embree sampler (``--rays``): uniform over the
        sphere, Owen-scrambled Sobol; Omega's standard error is below
        4 pi sqrt(p (1 - p) / N), and the fit averages M of them.
    r_far : float or None
        Outer radius of the field from its centre (mesh units); None = ``R_FAR_FACTOR``
        (8) bounding radii. Must exceed the bounding radius.
    model : {"cap", "paper", "table"}
        How Omega depends on r: 7 scalars per texel modelling the cap's half-angle
        (cap) or 1/Omega (paper, Kontkanen & Laine), or the sample table itself.
    prefilter : int
        Box prefilter over each texel's footprint: the raster sampler averages
        ``prefilter^2`` sub-directions, the Embree sampler spreads its rays over the
        footprint. 1 = point samples: the bilinear lookup already blurs over a texel
        and the contact ring is sharp.
    seed : int
        Key of the Embree sampler's ray sets (the raster sampler is deterministic).
    threads : int or None
        Worker threads (default: all cores); the result does not depend on it.
    """

    sampler: str = option(
        "raster",
        "Omega and Y at the sample points: CPU cube-map rasterizer or Embree rays.",
        kind=str,
        choices=SAMPLERS,
    )
    resolution: int = option(16, "Field texels per cube-face edge.", kind=int, low=1, high=256)
    radial_samples: int = option(15, "Sample distances per texel.", kind=int, low=3, high=256)
    raster_size: int = option(32, "Rasterizer cube-map edge (texels).", kind=int, low=1, high=1024)
    n_rays: int = option(1024, "Embree rays per sample point.", kind=int, low=1, high=2**20, flag="rays")
    r_far: float | None = option(
        None,
        "Outer radius of the field (mesh units).",
        kind=float,
        low=0,
        low_open=True,
        none=f"{R_FAR_FACTOR:g} x the bounding radius",
        finite=False,  # inf reaches fit_field, which names the occluder's radius in its refusal
    )
    model: str = option(
        "cap",
        "Radial model: 7 scalars per texel (cap: cap half-angle; paper: 1/Omega) or the sampled table.",
        kind=str,
        choices=MODELS,
    )
    prefilter: int = option(1, "Box prefilter: sub-directions per texel edge.", kind=int, low=1, high=16)
    seed: int = seed_option()
    threads: int | None = threads_option()

    def __post_init__(self):
        validate(self)


OPTIONS = FieldOptions
