"""Options of the disk method (light: no numpy, read by ``aobake --help``)."""

from __future__ import annotations

from dataclasses import dataclass

from ...options import (
    bounces_option,
    max_distance_option,
    measure_option,
    option,
    threads_option,
    validate,
)


@dataclass(frozen=True)
class BunnellOptions:
    """What a user chooses for :func:`aobake.methods.bunnell.bunnell_ao`.

    Attributes
    ----------
    passes : int
        Occlusion passes K >= 1; pass k weights each disk by its own accessibility from
        the geometry near it (double-shadow removal). One pass is the default: a second
        gains little for twice the time (docs/bunnell.md).
    theta : float
        Opening parameter of the cluster tree (> 0): a cluster is used whole only when
        every receiver of a bucket is at ``d^2 >= theta * max(A, pi b^2)`` from it.
        Larger = slower and more exact; 2 gives Embree's 16-ray time at about half its
        error (docs/bunnell.md).
    near : float
        Disks closer than ``sqrt(near * A)`` to a receiver become the exact form factor of
        their polygon cells (0 = disks only, as published; 4 removes the contact errors).
    directional : bool
        Per-direction saturation: layers stacked in one direction count once (off = the
        plain sum, as published).
    measure : {"cosine", "uniform"}
    max_distance : float or None
        Ignore disks farther than this (mesh units); None = unbounded.
    bounces : int
        A lit scene's indirect bounces K (0 = direct light only); unused without light.
    threads : int or None
        numba threads for the call (default: all cores); the result does not depend on it.
    """

    passes: int = option(1, "Occlusion passes (double-shadow removal).", kind=int, low=1)
    theta: float = option(
        2.0,
        "Opening parameter of the disk tree (larger = slower, more exact).",
        kind=float,
        low=0,
        low_open=True,
        finite=False,
    )
    near: float = option(
        4.0,
        "Disks closer than sqrt(NEAR * area) become exact polygons (0 = disks only).",
        kind=float,
        low=0,
    )
    directional: bool = option(
        True,
        "Per-direction saturation: layers stacked in one direction count once (off = the plain sum).",
        kind=bool,
    )
    measure: str = measure_option()
    max_distance: float | None = max_distance_option()
    bounces: int = bounces_option()
    threads: int | None = threads_option()

    def __post_init__(self):
        validate(self)


OPTIONS = BunnellOptions
