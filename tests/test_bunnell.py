"""The disk method's entry points (aobake.methods.bunnell.bunnell_ao, estimate): option
validation, errors, progress, the pipeline and the command line."""

from __future__ import annotations

import numba
import numpy as np
import pytest
import trimesh

from aobake.errors import NumericalError
from aobake.kernels import bunnell as K
from aobake.kernels import hierarchy as KH
from aobake.kernels import polygon as KP
from aobake.kernels import treepass as KT
from aobake.kernels import treewalk as KTW
from aobake.mesh import Surface, surface_from_arrays
from aobake.methods import bunnell as B
from aobake.methods.bunnell import passes as P
from aobake.methods.bunnell import tree as H
from aobake.testing.disk import (
    balls_over_floor,
    passes_of,
    small_scene,
)
from aobake.testing.scenes import (
    combine_meshes,
    facing_plates,
    ground_grid,
    icosphere,
    sphere_on_plane,
    touching_spheres,
)

# --------------------------------------------------------------------------------------
# API: validation, errors, progress


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(passes=0), "passes must be an integer >= 1"),
        (dict(passes=1.5), "passes must be an integer"),
        (dict(theta=0.0), "theta must be a number > 0"),
        (dict(theta=float("nan")), "theta must be a number > 0"),
        (dict(theta="8"), "theta must be a number > 0"),
        (dict(near=-1.0), "near must be a finite number >= 0"),
        (dict(near=float("inf")), "near must be a finite number >= 0"),
        (dict(sides="both"), "sides must be one of"),
        (dict(damping=0.0), "damping must be a finite number > 0 and <= 1"),
        (dict(damping=1.5), "damping must be a finite number > 0 and <= 1"),
        (dict(pass_reach=0.0), "pass_reach must be a number > 0"),
        (dict(measure="solid"), "measure must be one of"),
        (dict(max_distance=0.0), "max_distance must be a finite number > 0"),
        (dict(max_distance=float("inf")), "max_distance must be a finite number > 0"),
        (dict(combine="average"), "combine must be one of"),
        (dict(combine="bunnell", passes=1), "needs passes >= 2"),
        (dict(combine="hoberock", passes=1), "needs passes >= 2"),
        (dict(threads=0), "threads must be an integer >= 1"),
        (dict(leaf_size=0), "leaf_size must be an integer >= 1"),
    ],
)
def test_bad_options_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        B.variant_ao(touching_spheres(), **kwargs)


@pytest.mark.parametrize("exact", [True, False])
def test_non_finite_kernel_output_raises_numerical_error(monkeypatch, exact):
    module, name = (P._k, "brute_force_pass") if exact else (P._tp, "hierarchy_pass")

    def broken(*args):
        args[-3][:] = np.nan  # out (the first moments and the fill follow)

    monkeypatch.setattr(module, name, broken)
    with pytest.raises(NumericalError, match="^bunnell: .* non-finite"):
        B.variant_ao(touching_spheres(), exact=exact)


def test_progress_counts_every_receiver_of_every_pass():
    class Recorder:
        def __init__(self):
            self.total, self.done, self.finished = None, 0, False

        def start(self, total, label):
            self.total = total

        def advance(self, n):
            self.done += n

        def finish(self):
            self.finished = True

    s = touching_spheres()
    for exact, share in ((False, False), (True, True), (False, True)):
        rec = Recorder()
        B.variant_ao(s, passes=3, progress=rec, exact=exact, share_passes=share)
        assert rec.total == rec.done == 3 * s.n_vertices and rec.finished


def test_input_arrays_are_not_modified():
    s = small_scene()
    copies = [s.positions.copy(), s.faces.copy(), s.normals.copy()]
    B.variant_ao(s, passes=2)
    for before, after in zip(copies, [s.positions, s.faces, s.normals], strict=True):
        np.testing.assert_array_equal(before, after)


def test_float32_and_int32_inputs_are_coerced():
    s = touching_spheres()
    p32, n32 = s.positions.astype(np.float32), s.normals.astype(np.float32)
    s32 = Surface(p32, s.faces.astype(np.int32), n32, s.parts)
    s64 = Surface(p32.astype(np.float64), s.faces, n32.astype(np.float64), s.parts)
    ao = B.variant_ao(s32)
    assert ao.dtype == np.float64
    np.testing.assert_array_equal(ao, B.variant_ao(s64))


def test_each_kernel_compiled_once():
    """Coercion in the wrapper guarantees one specialization per kernel (no dtype drift)."""
    if numba.config.DISABLE_JIT:
        pytest.skip("JIT disabled")
    B.variant_ao(touching_spheres(), passes=2)
    B.variant_ao(touching_spheres(), passes=2, exact=True)
    B.variant_ao(touching_spheres(), measure="uniform", max_distance=0.5)
    for kernel in (
        K.brute_force_pass,
        KT.thin_pass,
        KT.hierarchy_pass_inlined,
        KTW.bucket_bounds,
        KH.build_tree,
        KH.node_geometry,
        KH.refit_nodes,
        KP.cell_corners,
        KP.vertex_areas,
    ):
        assert len(kernel.signatures) == 1, (kernel, kernel.signatures)


# --------------------------------------------------------------------------------------
# pipeline and command line


@pytest.fixture
def scene_ply(tmp_path):
    s = sphere_on_plane(subdivisions=2, cells=10)
    path = tmp_path / "scene.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(path)
    return path


def test_pipeline_bake_bunnell_is_the_api():
    import aobake

    s = sphere_on_plane()
    np.testing.assert_array_equal(aobake.bake(s, "bunnell", passes=2, theta=8.0),
                                  B.variant_ao(s, passes=2, theta=8.0))


@pytest.mark.parametrize("flag", [None, "--no-directional", "--directional"])
def test_cli_bunnell_writes_what_the_api_computes(scene_ply, tmp_path, flag):
    from click.testing import CliRunner

    from aobake.cli import main
    from aobake.io import load_mesh, read_bake

    out = tmp_path / "out.ply"
    args = ["bake", str(scene_ply), "-o", str(out), "--method", "bunnell", "--passes", "2",
            "--theta", "8", "--near", "2"] + ([flag] if flag else [])
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    expected = B.variant_ao(load_mesh(scene_ply), passes=2, theta=8.0, near=2.0,
                            directional=flag != "--no-directional")
    np.testing.assert_allclose(read_bake(out), expected, rtol=0, atol=1e-7)  # float32 in PLY
    assert "bunnell in" in result.stderr and "rays" not in result.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--method", "bunnell", "--rays", "8"], "--rays does not apply to --method bunnell"),
        (["--method", "bunnell", "--tolerance", "0.1"], "--tolerance does not apply"),
        (["--method", "embree", "--passes", "2"], "--passes does not apply to --method embree"),
        (["--method", "embree", "--theta", "2"], "--theta does not apply"),
        (["--method", "embree", "--no-directional"], "--directional does not apply"),
        (["--method", "bunnell", "--theta", "0"], "Invalid value for '--theta'"),
        (["--method", "bunnell", "--passes", "0"], "Invalid value for '--passes'"),
    ],
)
def test_cli_rejects_options_of_other_methods(scene_ply, tmp_path, args, message):
    from click.testing import CliRunner

    from aobake.cli import main

    out = tmp_path / "out.ply"
    result = CliRunner().invoke(main, ["bake", str(scene_ply), "-o", str(out), *args])
    assert result.exit_code == 2
    assert message in result.output
    assert not out.exists()


@pytest.mark.parametrize("pass_fill", [True, False])
def test_shared_passes_follow_the_full_ones(pass_fill):
    """Passes 2..K at one vertex per leaf and normal group, carried over as what they
    remove: close to every vertex computing them (the correction's error is a fraction
    of the correction), never darker than pass 1, and the vertices that do not cast
    (no normal, isolated) are evaluated themselves."""
    s = balls_over_floor()
    dense = combine_meshes(
        icosphere(3, center=(-1.1, 0.0, 0.2)), icosphere(3, center=(1.1, 0.0, 0.2)),
        ground_grid(3.0, 30, -1.0),
    )
    for scene in (s, dense, small_scene()):
        one = B.variant_ao(scene)
        shared = B.variant_ao(scene, passes=2, pass_fill=pass_fill)
        full = B.variant_ao(scene, passes=2, share_passes=False, pass_fill=pass_fill)
        assert np.all(shared >= one - 1e-6) and np.all(full >= one - 1e-6)
        correction = np.sqrt(np.mean((full - one) ** 2))
        assert correction > 5e-4
        assert np.sqrt(np.mean((shared - full) ** 2)) < 0.5 * correction
    extra = slice(-3, None)  # small_scene's flipped copy's no-normal and isolated vertices
    np.testing.assert_allclose(shared[extra], full[extra], rtol=0, atol=1e-3)


def test_node_coherence_matches_direct_sums():
    """|sum A m| / sum A per node, against a loop over each node's disks: 1 on a flat
    patch, ~0 for the root of two facing plates (their normals cancel)."""
    s = facing_plates(cells=6)
    e = B.build_elements(s)
    t = B.build_tree(e, leaf_size=4)
    c = H.node_coherence(t, e.normals, e.areas)
    for q in range(t.n_nodes):
        members = t.order[t.start[q] : t.stop[q]]
        a = e.areas[members]
        expect = np.linalg.norm((e.normals[members] * a[:, None]).sum(axis=0)) / a.sum()
        assert c[q] == pytest.approx(expect, abs=1e-12)
    assert c[0] < 1e-9  # the root holds both plates
    flat = [q for q in range(t.n_nodes) if np.ptp(e.positions[t.order[t.start[q] : t.stop[q]], 2]) == 0]
    assert len(flat) >= 4
    assert np.all(c[flat] > 1 - 1e-12)  # one plate: every normal equal


def test_node_coherence_and_tree_keys_are_the_numpy_formulations():
    """The compiled node coherence and tree keys give the bits of their numpy
    formulations (prefix sums by np.cumsum, np.linalg.norm; floor of the scaled offsets),
    on a shuffled scene at a large offset and on random normals and areas."""
    rng = np.random.default_rng(11)
    s = sphere_on_plane(subdivisions=3, cells=24)
    shuffle = rng.permutation(s.n_vertices)
    back = np.argsort(shuffle)
    s = surface_from_arrays(s.positions[shuffle] * 3e3 + 1e5, back[s.faces], s.normals[shuffle])
    e = B.build_elements(s)
    t = B.build_tree(e, leaf_size=8)
    for normals, areas in ((e.normals, e.areas),
                           (rng.normal(size=e.normals.shape), rng.uniform(0, 1e-3, e.n_vertices))):
        am = normals[t.order] * areas[t.order][:, None]
        cum = np.zeros((t.order.shape[0] + 1, 4))
        np.cumsum(np.column_stack([am, areas[t.order]]), axis=0, out=cum[1:])
        sums = cum[t.stop] - cum[t.start]
        with np.errstate(invalid="ignore", divide="ignore"):
            want = np.clip(np.nan_to_num(np.linalg.norm(sums[:, :3], axis=1) / sums[:, 3], nan=1.0), 0, 1)
        np.testing.assert_array_equal(H.node_coherence(t, normals, areas), want)
    from aobake.constants import TREE_KEY_STEPS

    for p in (e.positions[e.emitter_index], s.positions, rng.normal(size=(5000, 3)) * 1e-7 + 3.0):
        lo = p.min(axis=0)
        step = TREE_KEY_STEPS / float((p.max(axis=0) - lo).max())
        want = np.floor((p - lo) * step + 0.5).astype(np.int64)
        np.testing.assert_array_equal(H.tree_keys(p), want)
    rows = rng.choice(s.n_vertices, 300, replace=False)
    np.testing.assert_array_equal(H.tree_keys(s.positions, rows), H.tree_keys(s.positions[rows]))


def test_packed_nodes_open_incoherent_nodes_sooner():
    """The opening distance grows by 1 + OPEN_COHERENCE (1 - c) where theta decides it."""
    s = facing_plates(cells=6)
    e = B.build_elements(s)
    t = B.build_tree(e, leaf_size=4)
    c = H.node_coherence(t, e.normals, e.areas)
    plain = H.pack_nodes(t, theta=2.0, near=0.0)[:, KH.N_OPEN_D2].astype(np.float64)
    opened = H.pack_nodes(t, theta=2.0, near=0.0, coherence=c)[:, KH.N_OPEN_D2].astype(np.float64)
    ratio = 1.0 + H.OPEN_COHERENCE * (1.0 - c)
    np.testing.assert_allclose(opened, plain * ratio, rtol=1e-6)
    assert ratio.max() > 3.0  # some node mixes the two plates


def test_tree_error_on_facing_plates_shrinks_with_coherent_opening(monkeypatch):
    """Against the exact sum at theta 2: a node holding both plates has its centre in the
    gap between them and is a poor point emitter; opening such nodes sooner cuts the
    tree's error (measured 0.014 -> 0.0005 RMSE on this scene)."""
    s = facing_plates(cells=24, gap=0.5)
    e = B.build_elements(s)
    t = B.build_tree(e)
    exact = passes_of(e, None)[0]
    tree = passes_of(e, t, theta=2.0)[0]
    assert np.sqrt(np.mean((tree - exact) ** 2)) < 0.003
    monkeypatch.setattr(H, "OPEN_COHERENCE", 0.0)  # the published criterion
    published = passes_of(e, t, theta=2.0)[0]
    assert np.sqrt(np.mean((published - exact) ** 2)) > 0.01
