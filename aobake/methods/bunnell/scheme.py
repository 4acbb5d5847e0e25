"""The disk method's pass scheme: the switches the tests and the bench turn to compare the
published schemes with aobake's (fixed for users), and how the front and back sums and
the passes make the result."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ..._types import AOArray, FloatArray
from ...constants import PASS_GATE_WIDTH
from ...options import option, validate
from .options import BunnellOptions

# Emitters per leaf (and receivers per bucket): 16 to 64 cost about the same per pass;
# 32 and 64 are more accurate than 16 (docs/bunnell.md).
DEFAULT_LEAF_SIZE = 32
# The default of Scheme.pass_reach (see there).
DEFAULT_PASS_REACH = 0.5
# The default of Scheme.bucket_spread (see there; docs/bunnell.md, "Receiver buckets split
# at gaps").
DEFAULT_BUCKET_SPREAD = 32.0


@dataclass(frozen=True)
class Scheme:
    """The pass scheme's internal switches. The defaults are aobake's method; the others
    are the published schemes and variants the bench compares it with (docs/bunnell.md).

    Attributes
    ----------
    sides : {"max", "front"}
        How the front and back sums make the occlusion (:func:`combine_sides`).
    damping : float
        Pass k weights disk j by ``1 - damping A_{k-1}(j; pass_reach r)``.
    pass_reach : float
        > 0, or inf (weights from the whole previous pass). ``damping=1,
        pass_reach=inf, gate=0`` with ``near=0`` is Bunnell's published scheme.
    gate : float
        Width of the pass weights' gate (>= 0, 0 = ungated): see :func:`occlusion_passes`.
    pass_fill : bool
        Later passes remove occlusion from a direction bin only in proportion to how
        empty pass 1 left it (with ``directional``).
    share_passes : bool
        With a tree: passes 2..K at one vertex per leaf and normal group only.
    combine : {"last", "bunnell", "hoberock"}
        How the passes make the result (:func:`combine_passes`).
    leaf_size : int
        Maximum disks per tree leaf.
    bucket_spread : float
        A receiver bucket (a tree leaf) whose bounding sphere's cross-section exceeds this
        many times its disks' area is split (``passes.split_spread_buckets``); inf keeps
        every leaf whole.
    """

    sides: str = option("max", "front and back sums", kind=str, choices=("max", "front"))
    damping: float = option(1.0, "pass weight damping", kind=float, low=0, low_open=True, high=1)
    pass_reach: float = option(
        DEFAULT_PASS_REACH, "reach of the pass weights", kind=float, low=0, low_open=True, finite=False
    )
    gate: float = option(PASS_GATE_WIDTH, "gate width", kind=float, low=0)
    pass_fill: bool = option(True, "the fill rule", kind=bool)
    share_passes: bool = option(True, "later passes at representatives", kind=bool)
    combine: str = option(
        "last", "how passes combine", kind=str, choices=("last", "bunnell", "hoberock")
    )
    leaf_size: int = option(DEFAULT_LEAF_SIZE, "disks per leaf", kind=int, low=1)
    bucket_spread: float = option(
        DEFAULT_BUCKET_SPREAD, "bucket spread", kind=float, low=1, finite=False
    )

    def __post_init__(self):
        validate(self)


def settings(**keywords) -> tuple[BunnellOptions, Scheme]:
    """``(BunnellOptions, Scheme)`` from keywords of either (tests and the bench);
    ``TypeError`` for a name neither has."""
    names = {f.name for f in fields(BunnellOptions)}, {f.name for f in fields(Scheme)}
    unknown = sorted(set(keywords) - names[0] - names[1])
    if unknown:
        raise TypeError(f"no option or scheme switch {unknown[0]!r}")
    options = BunnellOptions(**{k: v for k, v in keywords.items() if k in names[0]})
    scheme = Scheme(**{k: v for k, v in keywords.items() if k in names[1]})
    return options, scheme


def check_blend(combine: str, passes: int) -> None:
    """The blends read the last two passes: ``ValueError`` for one with fewer than 2."""
    if combine != "last" and passes < 2:
        raise ValueError(
            f"combine={combine!r} blends the last two passes and needs passes >= 2, got {passes}"
        )


def combine_sides(sums: FloatArray, sides: str = "max") -> FloatArray:
    """Occlusion from the (front, back) sums of one pass.

    ``"front"``: the front sum (front faces cast, the published method). ``"max"``:
    ``max(front, back)``. Outside every closed object each direction crosses as many back
    faces as front faces, so back = front for exact sums and nothing changes; a receiver
    inside a closed object (sunk into it, or on a face it rests on) gets back =
    front + 1, i.e. fully occluded; behind an open sheet (a floor seen from below) the
    back faces count as the ray-traced reference counts them.
    """
    if sides == "front":
        return sums[:, 0].copy()
    return np.maximum(sums[:, 0], sums[:, 1])


def combine_passes(occlusion: FloatArray, combine: str = "last") -> AOArray:
    """Accessibility ``ao = 1 - A`` from the passes' occlusion.

    Parameters
    ----------
    occlusion : (K, n) float64 in [0, 1]
        From :func:`occlusion_passes`.
    combine : {"last", "bunnell", "hoberock"}
        ``"last"``: A_K. ``"bunnell"``: 0.4 A_{K-1} + 0.6 A_K (Bunnell's blend of passes 1
        and 2 when K = 2). ``"hoberock"``: on accessibilities a = 1 - A,
        0.7 min(a_{K-1}, a_K) + 0.3 max(a_{K-1}, a_K), a weighted minimum that leans to the
        darker pass because even passes are too light (Hoberock & Jia). Both blends need
        K >= 2.

    Returns
    -------
    ao : (n,) float64 in [0, 1]
    """
    occlusion = np.asarray(occlusion, dtype=np.float64)
    if occlusion.ndim != 2 or occlusion.shape[0] < 1:
        raise ValueError(f"occlusion must have shape (K, n) with K >= 1, got {occlusion.shape}")
    if combine not in ("last", "bunnell", "hoberock"):
        raise ValueError(f"combine must be one of last, bunnell, hoberock, got {combine!r}")
    check_blend(combine, occlusion.shape[0])
    last = 1.0 - occlusion[-1]
    if combine == "last":
        return last
    prev = 1.0 - occlusion[-2]
    if combine == "bunnell":
        return 1.0 - (0.4 * occlusion[-2] + 0.6 * occlusion[-1])
    return 0.7 * np.minimum(prev, last) + 0.3 * np.maximum(prev, last)
