"""The disk method's passes (aobake.methods.bunnell.passes): double-shadow removal, the
fill rule, shared passes and the published schemes as tests of the scheme's switches."""

from __future__ import annotations

import numpy as np
import pytest

from aobake.constants import DIRECTION_SECTORS, PASS_RADII
from aobake.kernels import bunnell as K
from aobake.methods import bunnell as B
from aobake.methods.bunnell import passes as P
from aobake.progress import NullProgress
from aobake.testing.disk import (
    balls_over_floor,
    kernel_sums,
    passes_of,
    small_scene,
)
from aobake.testing.naive_bunnell import naive_bunnell_ao
from aobake.testing.scenes import (
    combine_meshes,
    facing_plates,
    icosphere,
)

# --------------------------------------------------------------------------------------
# passes and their combination


@pytest.mark.parametrize("combine", ("last", "bunnell", "hoberock"))
@pytest.mark.parametrize("measure", ["cosine", "uniform"])
@pytest.mark.parametrize("gate", [0.0, 0.1])
@pytest.mark.parametrize("directional", [True, False])
def test_passes_and_combine_match_numpy_reference(combine, measure, gate, directional):
    """Ungated on facing plates (the gate leaves them at pass 1), gated on two balls over a
    floor."""
    s = facing_plates(cells=6) if gate == 0.0 else balls_over_floor()
    kw = dict(passes=3, measure=measure, combine=combine, near=4.0, damping=0.7,
              pass_reach=2.0, gate=gate)
    expected, occ = naive_bunnell_ao(s, sectors=DIRECTION_SECTORS if directional else 0, **kw)
    assert occ[0].max() > 0.2 and np.abs(occ[0] - occ[1]).max() > 0.01
    got = B.variant_ao(s, exact=True, directional=directional, **kw)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10)


@pytest.mark.parametrize("pass_fill", [True, False])
def test_pass_fill_matches_numpy_reference(pass_fill):
    """Later passes give back part of what they remove from each direction bin (as much
    as pass 1 filled it): the kernel against the numpy reference, with and without."""
    s = balls_over_floor()
    kw = dict(passes=3, near=4.0, pass_reach=2.0)
    expected, occ = naive_bunnell_ao(s, sectors=DIRECTION_SECTORS, pass_fill=pass_fill, **kw)
    other, _ = naive_bunnell_ao(s, sectors=DIRECTION_SECTORS, pass_fill=not pass_fill, **kw)
    assert np.abs(expected - other).max() > 1e-3  # the rule changes this scene
    got = B.variant_ao(s, exact=True, pass_fill=pass_fill, **kw)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10)


def _closed_room():
    """Two balls inside a closed ball whose faces point inward: every ray from every
    vertex hits a wall, so the occlusion is 1 everywhere."""
    p, f = icosphere(2, 1.0)
    return combine_meshes(
        icosphere(2, 0.3, (0.0, 0.0, -0.5)), icosphere(1, 0.2, (0.3, 0.3, 0.3)), (p, f[:, ::-1])
    )


def test_pass_fill_keeps_an_enclosure_dark():
    """Inside a closed room the walls are in the balls' shadow and in plain view of every
    vertex. Pass 2 weighs them down anyway; the bins pass 1 filled stay full, so pass 2
    stays at pass 1 (which is 0.93-1, the truth 1) instead of lightening by 0.06."""
    s = _closed_room()
    e = B.build_elements(s)
    ours = passes_of(e, None, passes=2, share_passes=False)
    plain = passes_of(e, None, passes=2, share_passes=False, pass_fill=False)
    np.testing.assert_array_equal(ours[0], plain[0])
    assert ours[0].min() > 0.9
    assert (plain[0] - plain[1]).max() > 0.05
    assert (ours[0] - ours[1]).max() < 0.006
    assert np.all(plain[1] <= ours[1] + 1e-12) and np.all(ours[1] <= ours[0] + 1e-12)
    tree = B.build_tree(e, leaf_size=4)
    got = passes_of(e, tree, passes=2, theta=np.inf, share_passes=False)
    np.testing.assert_allclose(got[1], ours[1], rtol=0, atol=2e-6)
    # shared: each vertex loses what its leaf's representative lost
    got = passes_of(e, tree, passes=2, theta=np.inf)
    np.testing.assert_allclose(got[1], ours[1], rtol=0, atol=2e-3)


def test_pass_fill_lies_between_the_plain_pass_and_pass_one():
    """Per vertex: plain pass 2 <= pass 2 with the fill rule <= pass 1 (the rule only
    gives back part of what the pass removed), and the rule matters on this scene."""
    s = balls_over_floor()
    e = B.build_elements(s)
    ours = passes_of(e, None, passes=2, share_passes=False)
    plain = passes_of(e, None, passes=2, share_passes=False, pass_fill=False)
    assert np.all(plain[1] <= ours[1] + 1e-12) and np.all(ours[1] <= ours[0] + 1e-12)
    assert (ours[1] - plain[1]).max() > 1e-3
    assert (ours[0] - ours[1]).max() > 1e-3  # and still removes double shadows


def test_combine_formulas():
    occ = np.array([[0.2, 0.9, 0.5], [0.4, 0.1, 0.5]])
    np.testing.assert_allclose(B.combine_passes(occ, "last"), [0.6, 0.9, 0.5])
    np.testing.assert_allclose(B.combine_passes(occ, "bunnell"), 1 - (0.4 * occ[0] + 0.6 * occ[1]))
    # accessibilities 0.8 / 0.6, 0.1 / 0.9, 0.5 / 0.5: weighted minimum leans dark
    np.testing.assert_allclose(B.combine_passes(occ, "hoberock"), [0.66, 0.34, 0.5])
    np.testing.assert_allclose(B.combine_passes(occ[:1], "last"), [0.8, 0.1, 0.5])


def test_combine_sides():
    sums = np.array([[0.3, 0.1], [0.2, 1.4], [0.0, 0.0]])
    np.testing.assert_array_equal(B.combine_sides(sums, "front"), [0.3, 0.2, 0.0])
    np.testing.assert_array_equal(B.combine_sides(sums, "max"), [0.3, 1.4, 0.0])


@pytest.mark.parametrize("gate", [0.0, 0.1])
@pytest.mark.parametrize("pass_reach", [0.5, np.inf])
def test_later_passes_lighten_double_shadows(pass_reach, gate):
    s = balls_over_floor()
    e = B.build_elements(s)
    kw = dict(passes=2, pass_reach=pass_reach, gate=gate, share_passes=False)
    occ = passes_of(e, None, **kw)
    assert np.all(occ[1] <= occ[0] + 1e-15)
    assert occ[1].mean() < occ[0].mean() and (occ[0] - occ[1]).max() > 5e-3
    tree = B.build_tree(e, leaf_size=4)
    np.testing.assert_allclose(
        passes_of(e, tree, theta=np.inf, **kw), occ, rtol=0, atol=2e-6
    )


def test_single_layer_does_not_collapse():
    """Facing plates: one layer, no double shadow. Bunnell's weights (the whole previous
    pass: pass_reach = inf) make pass 2 collapse toward open; weights from the geometry
    near each emitter only keep pass 2 close to pass 1, and the gate (the default) leaves
    it at pass 1: what occludes a plate is the other plate, behind every receiver's
    tangent plane there."""
    s = facing_plates(cells=8)
    e = B.build_elements(s)
    # the bins' fill (pass_fill) would hold these up: the weights alone here
    published = passes_of(e, None, passes=2, pass_reach=np.inf, gate=0.0, pass_fill=False)
    reach = passes_of(e, None, passes=2, gate=0.0, pass_fill=False)
    ours = passes_of(e, None, passes=2)
    centre = np.abs(s.positions[:, :2]).max(axis=1) < 0.3
    assert published[1][centre].mean() < 0.5 * published[0][centre].mean()
    assert reach[1][centre].mean() > 0.9 * reach[0][centre].mean()
    assert reach[1][centre].mean() < reach[0][centre].mean() - 1e-3
    np.testing.assert_allclose(ours[1], ours[0], rtol=0, atol=1e-12)
    tree = B.build_tree(e, leaf_size=4)
    for share in (False, True):  # row 0 is the representatives' pass 1 when shared
        one = passes_of(e, tree, theta=np.inf)[0]
        two = passes_of(e, tree, passes=2, theta=np.inf, share_passes=share)[1]
        np.testing.assert_allclose(two, one, rtol=0, atol=1e-6)
        # clusters of both plates put their occluder centroids a little off the plane
        # (more so at the shared passes' opening parameter, theta / 2)
        one = passes_of(e, tree)[0]
        two = passes_of(e, tree, passes=2, share_passes=share)[1]
        np.testing.assert_allclose(two, one, rtol=0, atol=5e-3)
        assert np.all(two <= one + 1e-6)


def test_cumulative_bins_match_max_distance():
    """The distance bins of a pass are the sums with max_distance = each bin radius."""
    s = small_scene()
    e = B.build_elements(s)
    job = P._Pass(e, None, 4.0, 4.0, K.MEASURE_COSINE, np.inf)
    binned = job.sums(np.ones(e.n_vertices), NullProgress(), binned=True)[0]
    for b, radius in enumerate(PASS_RADII[:-1]):
        # the bins below the total are plain sums (no per-direction saturation)
        cut = kernel_sums(e, None, np.ones(e.n_vertices), max_distance=radius * e.scale * (1 - 1e-12),
                    directional=False)
        np.testing.assert_allclose(binned[:, :, b], cut[:, :, -1], rtol=0, atol=1e-12)
    total = kernel_sums(e, None, np.ones(e.n_vertices))[:, :, -1]
    np.testing.assert_allclose(binned[:, :, -1], total, rtol=0, atol=1e-12)


def test_one_level_weights_give_the_same_sums():
    """A pass whose weight levels are all equal reads level 0 only: (n,) weights (one
    level in the tree's tables) give bit for bit the sums of tables of N_LEVELS levels,
    with and without a tree, and a leveled pass after it grows the tables."""
    s = small_scene()
    e = B.build_elements(s)
    rng = np.random.default_rng(3)
    w = rng.uniform(0.2, 1.0, e.n_vertices)
    for tree in (None, B.build_tree(e, leaf_size=4)):
        one = P._Pass(e, tree, 2.0, 4.0, K.MEASURE_COSINE, np.inf)
        spread = P._Pass(e, tree, 2.0, 4.0, K.MEASURE_COSINE, np.inf)
        if tree is not None:
            spread._levels(K.N_LEVELS)  # the tables of every level, as a leveled pass has
        for binned in (False, True):
            a, fa = one.sums(w, NullProgress(), binned=binned)
            b, fb = spread.sums(np.repeat(w[:, None], K.N_LEVELS, axis=1), NullProgress(), binned=binned)
            np.testing.assert_array_equal(a, b)
            np.testing.assert_array_equal(fa, fb)
        if tree is not None:
            assert one.weights.shape == (e.n_emitters, 1)
            assert one.moments.shape[1] == 1
            levels = np.repeat(w[:, None], K.N_LEVELS, axis=1) * np.linspace(1.0, 0.5, K.N_LEVELS)
            a = one.sums(levels, NullProgress())[0]  # leveled: grown to N_LEVELS
            assert one.weights.shape == (e.n_emitters, K.N_LEVELS)
            np.testing.assert_array_equal(a, spread.sums(levels, NullProgress())[0])


def test_scratch_is_a_writable_array_of_its_shape():
    """The pass's list buffers (passes.scratch): C-contiguous, writable, the asked shape
    and dtype (numba types them as numpy's own), empty shapes included."""
    for shape, dtype in (((2, 18, 1000), np.float32), ((2, 2, 7), np.int64), ((2, 26, 0), np.float32)):
        a = P.scratch(shape, dtype)
        assert a.shape == shape and a.dtype == dtype
        assert a.flags.c_contiguous and a.flags.writeable and a.flags.aligned
        a[...] = 1
        assert np.all(a == 1)
