"""Bent normals (``bent_normals=True``, ``--bent-normals``): the cosine-weighted mean
unoccluded direction, from the AO rays themselves, against the closed form of a point
on a floor beside a wall."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from plyfile import PlyData

from aobake.cli import main
from aobake.io import load_mesh, read_bake
from aobake.mesh import surface_from_arrays
from aobake.methods.embree import embree_ao
from aobake.methods.embree.estimator import estimate
from aobake.methods.embree.options import EmbreeOptions
from aobake.testing import scenes

#: A receiver at distance D from an (effectively infinite) wall x = D; everything that
#: escapes is the quarter sphere x < 0, z > 0. Cosine-weighted mean direction: x-part
#: -int |x| z = -2/3, z-part int z^2 = pi/3 over that quarter.
D, L = 1.0, 2000.0
EXPECTED = np.array([-2.0 / 3.0, 0.0, np.pi / 3.0]) / np.hypot(2.0 / 3.0, np.pi / 3.0)


def _floor_and_wall():
    """A tiny receiver triangle at the origin facing +z, and a huge wall at x = D facing -x."""
    receiver = np.array([[0.0, 0.0, 0.0], [1e-3, 0.0, 0.0], [0.0, 1e-3, 0.0]])
    wall = np.array([[D, -L, 0.0], [D, L, 0.0], [D, L, L], [D, -L, L]])
    faces = np.array([[0, 1, 2], [3, 5, 4], [3, 6, 5]])
    normals = np.array([[0, 0, 1.0]] * 3 + [[-1.0, 0, 0]] * 4)
    return surface_from_arrays(np.vstack([receiver, wall]), faces, normals)


@pytest.mark.parametrize("measure", ["cosine", "uniform"])
def test_bent_normal_beside_a_wall_is_the_closed_form(measure):
    result = embree_ao(_floor_and_wall(), n_rays=4096, seed=1, measure=measure, bent_normals=True)
    bent = result.bent_normals[0]
    assert np.linalg.norm(bent) == pytest.approx(1.0, abs=1e-12)
    angle = np.degrees(np.arccos(np.clip(bent @ EXPECTED, -1, 1)))
    assert angle < 0.3, (bent, EXPECTED)  # measured: 0.002 (cosine), 0.04 (uniform) degrees
    assert abs(bent[1]) < 0.03  # the wall is symmetric in y


def test_bent_normal_of_an_open_vertex_is_its_normal():
    """A vertex of a convex body sees only open sky about its normal: symmetric rays."""
    surface = scenes.icosphere(2)
    result = embree_ao(surface_from_arrays(*surface), n_rays=1024, seed=2, bent_normals=True)
    normals = surface_from_arrays(*surface).normals
    cosines = np.sum(result.bent_normals * normals, axis=1)
    assert cosines.min() > 0.995


def test_fully_occluded_vertex_gets_its_normal():
    inside = scenes.sphere(1.0, 1, inward=True)
    result = embree_ao(inside, n_rays=64, seed=0, bent_normals=True)
    assert (result.ao == 0.0).all()
    np.testing.assert_array_equal(result.bent_normals, inside.normals)


def test_ao_is_bit_identical_with_bent_normals_and_bent_normals_for_any_threads():
    surface = scenes.sphere_on_plane(1, 8)
    plain = embree_ao(surface, n_rays=64, seed=5, threads=1)
    options = EmbreeOptions(n_rays=64, seed=5, bent_normals=True, threads=2)
    split = estimate(surface, options, chunk_rays=16)  # a vertex's rays span chunks
    one = embree_ao(surface, n_rays=64, seed=5, threads=1, bent_normals=True)
    np.testing.assert_array_equal(plain.ao, one.ao)
    np.testing.assert_array_equal(split.ao, one.ao)
    np.testing.assert_array_equal(split.bent_normals, one.bent_normals)
    assert plain.bent_normals is None
    assert np.isfinite(one.bent_normals).all()
    # adaptive rounds add to the same sums
    adaptive = embree_ao(surface, n_rays=256, seed=5, tolerance=0.05, bent_normals=True)
    assert np.allclose(np.linalg.norm(adaptive.bent_normals, axis=1), 1.0)


def test_vertex_ranges_concatenate_to_the_whole(tmp_path):
    surface = scenes.sphere_on_plane(1, 6)
    options = EmbreeOptions(n_rays=32, seed=4, bent_normals=True)
    whole = estimate(surface, options)
    n = surface.n_vertices
    pieces = [estimate(surface, options, vertices=(lo, hi)) for lo, hi in ((0, n // 3), (n // 3, n))]
    np.testing.assert_array_equal(np.vstack([p.bent_normals for p in pieces]), whole.bent_normals)


def test_cli_writes_bent_normal_beside_ao(tmp_path):
    surface = scenes.sphere_on_plane(1, 6)
    from aobake.io import write_ply

    write_ply(tmp_path / "in.ply", surface.positions, surface.faces, np.ones(surface.n_vertices))
    out = tmp_path / "out.ply"
    args = ["bake", str(tmp_path / "in.ply"), "-o", str(out), "--rays", "32", "--seed", "3", "--quiet"]
    result = CliRunner().invoke(main, [*args, "--bent-normals"])
    assert result.exit_code == 0, result.output
    data = PlyData.read(str(out))["vertex"].data
    bent = np.column_stack([data[f"bentNormal_{c}"] for c in "xyz"])
    reference = embree_ao(load_mesh(tmp_path / "in.ply"), n_rays=32, seed=3, bent_normals=True)
    np.testing.assert_array_equal(bent, reference.bent_normals.astype(np.float32))
    # the same ao as without the option
    plain = tmp_path / "plain.ply"
    assert CliRunner().invoke(main, ["bake", str(tmp_path / "in.ply"), "-o", str(plain), *args[4:]]).exit_code == 0
    np.testing.assert_array_equal(read_bake(out), read_bake(plain))


def test_cli_bent_normals_with_another_method_is_a_usage_error(tmp_path):
    surface = scenes.box()
    from aobake.io import write_ply

    write_ply(tmp_path / "in.ply", surface.positions, surface.faces, np.ones(surface.n_vertices))
    result = CliRunner().invoke(
        main, ["bake", str(tmp_path / "in.ply"), "-o", str(tmp_path / "o.ply"), "--method", "bunnell", "--bent-normals"]
    )
    assert result.exit_code == 2
    assert "--bent-normals" in result.output and "bunnell" in result.output
    assert not (tmp_path / "o.ply").exists()


def test_split_weld_and_receivers_carry_bent_normals(tmp_path):
    """Ranges stitched equal the whole bake; a weld writes the welded mesh's bent normal per
    input vertex; vertices not received get their normal."""
    from aobake.io import write_bake
    from aobake.mesh import weld_vertices
    from aobake.pipeline import bake_file, bake_part, write_parts

    def bent(path):
        data = PlyData.read(str(path))["vertex"].data
        return np.column_stack([data[f"bentNormal_{c}"] for c in "xyz"])

    pytest.importorskip("pxr")
    surface = scenes.combine_meshes(scenes.ground_grid(2.0, 6), scenes.icosphere(1, 0.5, (0, 0, 0.6)),
                                    names=["floor", "ball"])  # fmt: skip
    source = tmp_path / "in.usda"
    write_bake(source, surface, np.ones(surface.n_vertices))
    kw = dict(n_rays=32, seed=1, bent_normals=True)
    bake_file(source, tmp_path / "whole.ply", **kw)
    parts = [bake_part(source, parts=(k, 3), **kw) for k in range(3)]
    write_parts(source, tmp_path / "split.ply", parts, **kw)
    np.testing.assert_array_equal(bent(tmp_path / "split.ply"), bent(tmp_path / "whole.ply"))

    bake_file(source, tmp_path / "welded.ply", weld=True, **kw)
    loaded = load_mesh(source)
    welded, inverse = weld_vertices(loaded)
    expected = embree_ao(welded, n_rays=32, seed=1, bent_normals=True).bent_normals[inverse]
    np.testing.assert_array_equal(bent(tmp_path / "welded.ply"), expected.astype(np.float32))

    bake_file(source, tmp_path / "ball.ply", receivers=("/Root/ball",), **kw)
    floor = loaded.parts[0]
    got, whole = bent(tmp_path / "ball.ply"), bent(tmp_path / "whole.ply")
    np.testing.assert_array_equal(got[: floor.vertex_stop], loaded.normals[: floor.vertex_stop].astype(np.float32))
    np.testing.assert_array_equal(got[floor.vertex_stop :], whole[floor.vertex_stop :])
    # split, the first range holding no receiver at all
    parts = [bake_part(source, vertices=r, receivers=("/Root/ball",), **kw)
             for r in ((0, floor.vertex_stop), (floor.vertex_stop, loaded.n_vertices))]  # fmt: skip
    assert parts[0].attributes == {}
    write_parts(source, tmp_path / "ball_split.ply", parts, receivers=("/Root/ball",), **kw)
    np.testing.assert_array_equal(bent(tmp_path / "ball_split.ply"), got)
