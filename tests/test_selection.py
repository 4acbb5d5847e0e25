"""Who casts, who receives: ``--occluders`` / ``--receivers`` against bakes of the
selected parts alone, and the input's own ``ao`` kept where nothing is baked."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from aobake.batch import Settings, bake_arguments
from aobake.cli import main
from aobake.errors import InputError
from aobake.io import load_mesh, read_bake, write_bake
from aobake.pipeline import bake_file
from aobake.selection import kept_ao
from aobake.testing import scenes

RAYS = 64


def _parts(names=("floor", "ball", "box")):
    """A floor, a ball resting above it and a box beside the ball (last, so dropping it
    keeps every other vertex's index and rays)."""
    floor = scenes.ground_grid(2.0, 8, 0.0)
    ball = scenes.icosphere(1, 0.5, (0.0, 0.0, 0.55))
    box_points = np.array([[x, y, z] for x in (0.6, 1.2) for y in (-0.3, 0.3) for z in (0.01, 0.8)])
    box = (box_points, np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                                 [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]]))  # fmt: skip
    meshes = dict(zip(("floor", "ball", "box"), (floor, ball, box), strict=True))
    return scenes.combine_meshes(*(meshes[n] for n in names), names=list(names))


def _usd(tmp_path, names=("floor", "ball", "box")):
    """The parts as a USD file: prims /Root/floor, /Root/ball, /Root/box."""
    pytest.importorskip("pxr")
    path = tmp_path / f"{'_'.join(names)}.usda"
    surface = _parts(names)
    write_bake(path, surface, np.ones(surface.n_vertices))
    return path


def _bake(tmp_path, source, name="out.ply", method="embree", **kwargs):
    options = {"n_rays": RAYS, "seed": 2} if method == "embree" else {}
    bake_file(source, tmp_path / name, method=method, **options, **kwargs)
    return read_bake(tmp_path / name)


@pytest.mark.parametrize("method", ["embree", "bunnell"])
def test_an_occluder_left_out_equals_the_mesh_without_it(tmp_path, method):
    whole, without = _usd(tmp_path), _usd(tmp_path, ("floor", "ball"))
    selected = _bake(tmp_path, whole, "sel.ply", method, occluders=("/Root/floor", "*/ba*"))
    alone = _bake(tmp_path, without, "alone.ply", method)
    full = _bake(tmp_path, whole, "full.ply", method)
    n = len(alone)
    # same vertices, same rays, the same triangles traced: equal up to the float32 frame
    assert np.abs(selected[:n] - alone).max() <= (1.0 / RAYS if method == "embree" else 1e-6)  # measured: 0
    assert np.abs(full[:n] - alone).max() > 0.1  # the box does shade the others
    # the box itself still receives (from the floor and ball), and is written
    assert selected.shape == full.shape and (selected[n:] < 1.0).any()
    assert (selected[n:] >= full[n:] - 2.5 / RAYS).all()  # fewer occluders: never darker


def test_selected_receivers_equal_the_full_bake_and_the_rest_stays_open(tmp_path):
    surface = _parts()
    full = _bake(tmp_path, _usd(tmp_path), "full.ply")
    only = _bake(tmp_path, _usd(tmp_path), "ball.ply", receivers=("/Root/ball",))
    ball = surface.parts[1]
    s = slice(ball.vertex_start, ball.vertex_stop)
    np.testing.assert_array_equal(only[s], full[s])  # embree bakes just the range: same rays
    rest = np.ones(surface.n_vertices, dtype=bool)
    rest[s] = False
    assert (only[rest] == 1.0).all()  # no ao in the input: 1.0


@pytest.mark.parametrize("method", ["embree", "bunnell"])
def test_receivers_under_a_ground_plane_equal_the_full_bake_with_it(tmp_path, method):
    surface = _parts()
    source = _usd(tmp_path)
    full = _bake(tmp_path, source, "full.ply", method, ground=-0.2, up_axis="Z")
    bare = _bake(tmp_path, source, "bare.ply", method)
    only = _bake(tmp_path, source, "ball.ply", method, ground=-0.2, up_axis="Z", receivers=("/Root/ball",))
    ball = surface.parts[1]
    s = slice(ball.vertex_start, ball.vertex_stop)
    assert np.abs(full[s] - bare[s]).max() > 0.01  # the plane does shade the ball
    np.testing.assert_array_equal(only[s], full[s])
    rest = np.ones(surface.n_vertices, dtype=bool)
    rest[s] = False
    assert (only[rest] == 1.0).all()


def test_bunnell_receivers_keep_the_input_elsewhere(tmp_path):
    surface = _parts()
    full = _bake(tmp_path, _usd(tmp_path), "full.ply", "bunnell")
    only = _bake(tmp_path, _usd(tmp_path), "ball.ply", "bunnell", receivers=("*/ba?l",))
    ball = surface.parts[1]
    np.testing.assert_array_equal(only[ball.vertex_start : ball.vertex_stop], full[ball.vertex_start : ball.vertex_stop])
    assert (only[: ball.vertex_start] == 1.0).all() and (only[ball.vertex_stop :] == 1.0).all()


def test_kept_ao_reads_a_ply_inputs_own_ao(tmp_path):
    """A PLY is one part (named after the file): its stored ao is what it keeps."""
    surface = _parts()
    stored = np.linspace(0.2, 0.9, surface.n_vertices)
    write_bake(tmp_path / "in.ply", surface, stored)
    np.testing.assert_array_equal(kept_ao(load_mesh(tmp_path / "in.ply")), stored.astype(np.float32))
    assert (kept_ao(surface) == 1.0).all()  # arrays hold no ao


def test_usd_and_gltf_inputs_keep_their_stored_ao(tmp_path):
    pytest.importorskip("pxr")
    import gltf_assets as ga

    # glTF: bake once with every receiver, then again receiving only the ground
    glb = ga.write_scene(tmp_path / "scene.glb")
    bake_file(glb, tmp_path / "first.glb", n_rays=RAYS, seed=2)
    first = read_bake(tmp_path / "first.glb")
    rebaked = load_mesh(tmp_path / "first.glb")
    bake_file(tmp_path / "first.glb", tmp_path / "second.glb", n_rays=RAYS, seed=9, receivers=("ground",))
    second = read_bake(tmp_path / "second.glb")
    ground = next(p for p in rebaked.parts if p.name == "ground")
    s = slice(ground.vertex_start, ground.vertex_stop)
    rest = np.ones(len(first), dtype=bool)
    rest[s] = False
    np.testing.assert_array_equal(second[rest], first[rest])  # stored _AO kept
    assert not np.array_equal(second[s], first[s])  # another seed: baked again

    # USD: a full copy holding ao, re-baked receiving one prim only
    from test_io_attributes import _usd_source

    source = _usd_source(tmp_path / "in.usda")
    bake_file(source, tmp_path / "copy.usda", n_rays=RAYS, seed=2, overlay=False)
    first = read_bake(tmp_path / "copy.usda")
    bake_file(tmp_path / "copy.usda", tmp_path / "again.usda", n_rays=RAYS, seed=9, receivers=("/World/b/*",))
    again = read_bake(tmp_path / "again.usda")
    tet = load_mesh(source).parts[0]
    np.testing.assert_array_equal(again[: tet.vertex_stop], first[: tet.vertex_stop])
    assert not np.array_equal(again[tet.vertex_stop :], first[tet.vertex_stop :])


def test_stored_usd_ao_is_read_from_the_file_not_a_stale_layer(tmp_path):
    """A caller holding a stage on the input keeps its old layer registered; the ao kept at
    vertices not baked is the file's as it is on disk now."""
    pytest.importorskip("pxr")
    from pxr import Usd

    source = _usd(tmp_path)
    surface = load_mesh(source)
    held = Usd.Stage.Open(str(source))  # registers the layer holding ao = 1
    try:
        stored = np.linspace(0.1, 0.9, surface.n_vertices)
        write_bake(source, _parts(), stored)  # the file on disk now holds other values
        np.testing.assert_array_equal(kept_ao(load_mesh(source)), stored.astype(np.float32))
        out = _bake(tmp_path, source, "ball.ply", receivers=("/Root/ball",))
        ball = next(p for p in surface.parts if p.name == "ball")
        rest = np.ones(surface.n_vertices, dtype=bool)
        rest[ball.vertex_start : ball.vertex_stop] = False
        np.testing.assert_array_equal(out[rest], stored.astype(np.float32)[rest])
    finally:
        del held


def test_a_pattern_that_matches_nothing_is_one_line(tmp_path):
    surface = _parts()
    source = _usd(tmp_path)
    with pytest.raises(InputError, match=r"--occluders 'wall\*' matches no part; parts: /Root/floor, /Root/ball, /Root/box$"):
        bake_file(source, tmp_path / "o.ply", n_rays=4, occluders=("*floor", "wall*"))
    assert not (tmp_path / "o.ply").exists()
    write_bake(tmp_path / "in.ply", surface, np.ones(surface.n_vertices))
    result = CliRunner().invoke(
        main, ["bake", str(tmp_path / "in.ply"), "-o", str(tmp_path / "o.ply"), "--receivers", "/World/*", "-q"]
    )
    assert result.exit_code == 1
    assert result.output.strip().count("\n") == 0
    assert "--receivers '/World/*' matches no part; parts: in" in result.output
    assert not (tmp_path / "o.ply").exists()


def test_cli_patterns_reach_the_bake_and_batch_commands(tmp_path):
    surface = _parts()
    write_bake(tmp_path / "in.usda", surface, np.ones(surface.n_vertices))
    args = ["bake", str(tmp_path / "in.usda"), "-o", str(tmp_path / "o.ply"), "--rays", "16", "-q"]
    result = CliRunner().invoke(main, [*args, "--occluders", "/Root/floor", "--occluders", "/Root/ball"])
    assert result.exit_code == 0, result.output
    settings = Settings(receivers=("/Root/b*",), occluders=("/Root/floor",))
    assert bake_arguments(settings)[-4:] == ["--receivers", "/Root/b*", "--occluders", "/Root/floor"]
