"""The disk method's entry points: :func:`bunnell_ao` for users, :func:`estimate` with the
scheme's switches for tests and the bench, and :func:`run` for the method registry."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..._types import AOArray
from ...checks import check_result, mesh_threads, numba_threads
from ...ground import Ground, plane_occlusion, reach_cosines
from ...mesh import Surface
from ...options import build
from ...progress import Progress
from .. import MethodResult
from .elements import build_elements
from .options import BunnellOptions
from .passes import build_tree, occlusion_passes
from .scheme import Scheme, check_blend, combine_passes, settings
from .tree import ClusterTree, refit_tree


def bunnell_ao(
    surface: Surface,
    options: BunnellOptions | None = None,
    *,
    tree: ClusterTree | None = None,
    progress: Progress | None = None,
    ground: Ground | None = None,
    **changes,
) -> AOArray:
    """Per-vertex ambient accessibility from summed form factors (no rays).

    Each vertex i is a disk (centre p_i, unit normal n_i, area A_i = 1/3 of its triangles'
    area); disk j occludes receiver i by

    - cosine measure (default, matches the ray-traced reference):
      ``F = A_j |cos_e| cos_r / (pi r^2 + A_j)``;
    - uniform measure: ``F = (1 - r / sqrt(A_j / pi + r^2)) |cos_e| clamp(4 cos_r, 0, 1)``,

    with ``d = p_j - p_i``, ``r = |d|``, ``cos_r = max(n_i.d / r, 0)``, ``cos_e = -n_j.d / r``.
    Disks whose front side faces the receiver add to the front sum, the others to the
    back sum. Near the receiver (``r^2 < near A_j``) a disk is replaced by the exact form
    factor (cosine) or solid angle (uniform) of its barycentric cell, clipped to the
    receiver's tangent plane (Hoberock & Jia's fix for contacts). Far clusters of disks
    count as one emitter.

    Parameters
    ----------
    surface : Surface
        All parts form one scene and occlude each other.
    options : BunnellOptions, optional
        ``passes``, ``theta``, ``near``, ``directional``, ``measure``, ``max_distance``,
        ``threads`` (see :class:`BunnellOptions`); keywords override them:
        ``bunnell_ao(surface, theta=4)``.
    tree : ClusterTree or None, optional
        For animation: the tree of an earlier frame of the same mesh (from
        :func:`build_tree` on its :func:`build_elements`). It is refit to this frame's
        positions instead of rebuilt; rebuilt anyway when the set of casting disks
        changed. A tree whose clusters the motion has scrambled is only slower.
    progress : Progress or None, optional
        Advanced per chunk of receivers over all passes.
    ground : aobake.ground.Ground, optional
        An infinite occluding plane: its exact occlusion, cosine-weighted over the cone
        within ``max_distance`` and clipped to the receiver's hemisphere, joins the sums
        bin by bin (:func:`aobake.methods.bunnell.passes.occlusion_passes`).

    Returns
    -------
    ao : (n,) float64 in [0, 1]
        Accessibility 1 - A, 1 = fully open, in input vertex order.

    Raises
    ------
    ValueError
        An option is out of range.
    NumericalError
        The result is not finite or not in [0, 1] (a bug).

    Notes
    -----
    Receivers sit NEAR_OFFSET_REL edge lengths above their vertex along the normal (the
    analogue of a ray origin offset). Skipped without dividing by zero: the receiver's
    own disk and coincident disks (split vertices). Disks with zero area or no normal
    cast nothing but still receive. A receiver without a normal uses disks only and the
    occluded fraction of the full sphere. Coordinates are recentred and normalised in
    float64 before the float32 kernels: the method is scale and translation invariant.
    """
    return estimate(surface, build(BunnellOptions, options, **changes), progress, tree=tree, ground=ground)


def run(
    surface: Surface, options: BunnellOptions, progress: Progress | None = None, ground: Ground | None = None
) -> MethodResult:
    """The method interface (:mod:`aobake.methods`)."""
    return MethodResult(estimate(surface, options, progress, ground=ground))


def estimate(
    surface: Surface,
    options: BunnellOptions,
    progress: Progress | None = None,
    *,
    scheme: Scheme | None = None,
    exact: bool = False,
    tree: ClusterTree | None = None,
    ground: Ground | None = None,
) -> AOArray:
    """:func:`bunnell_ao` with the knobs tests and the bench turn: ``scheme`` (the published
    pass schemes and variants, :class:`Scheme`) and ``exact=True`` (every disk summed,
    O(n^2), no tree: the hierarchy's reference)."""
    scheme = Scheme() if scheme is None else scheme
    check_blend(scheme.combine, options.passes)  # before any work
    if not exact and options.passes == 1 and options.measure == "cosine":
        from ... import precompile

        # the tree pass's kernel, when not cached, compiles in a helper meanwhile (the CLI)
        precompile.start("tree-pass", threads=options.threads)
    options = dataclasses.replace(options, threads=mesh_threads(options.threads, surface.n_vertices))
    with numba_threads(options.threads):
        return _estimate(surface, options, progress, scheme, exact, tree, ground)


def _estimate(surface, options, progress, scheme, exact, tree, ground) -> AOArray:
    """:func:`estimate` once its inputs are checked."""
    elements = build_elements(surface)
    given, tree = tree, None
    if not exact and elements.n_emitters > 0:
        same = given is not None and np.array_equal(np.sort(given.order), elements.emitter_index)
        if same:
            tree = refit_tree(given, elements.positions, elements.areas)
        else:
            tree = build_tree(elements, leaf_size=scheme.leaf_size)
    plane = None
    if ground is not None:
        heights = ground.heights(surface.positions)
        plane = (
            ground.axis,
            reach_cosines(heights, options.max_distance),
            plane_occlusion(heights, elements.normals, ground.axis, options.measure, options.max_distance),
        )
    occlusion = occlusion_passes(elements, tree, options, scheme, progress=progress, plane=plane)
    ao = combine_passes(occlusion, scheme.combine)
    check_result(ao, "ao", lower=0.0, upper=1.0, method="bunnell")
    return ao


def variant_ao(
    surface: Surface,
    *,
    exact: bool = False,
    tree: ClusterTree | None = None,
    progress: Progress | None = None,
    **keywords,
) -> AOArray:
    """:func:`estimate` with options and scheme switches as keywords alike (tests, bench):
    ``variant_ao(surface, passes=2, pass_fill=False, exact=True)``."""
    options, scheme = settings(**keywords)
    return estimate(surface, options, progress, scheme=scheme, exact=exact, tree=tree)
