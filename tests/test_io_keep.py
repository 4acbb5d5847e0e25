"""Keeping the user's asset: PLY elements and properties written back whole, colour
encodings, ``--channel`` packing, the recorded up axis, ``--weld``. Read back with
plyfile (an independent reader)."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st
from plyfile import PlyData, PlyElement

from aobake.cli import main
from aobake.io import load_mesh, read_bake, write_bake
from aobake.io.color import linear_to_srgb, quantize, srgb_bytes, srgb_to_linear
from aobake.mesh import weld_vertices
from aobake.pipeline import bake_file, preview_file
from aobake.testing import scenes
from aobake.tools.preview import render_values

# -- colour encodings ----------------------------------------------------------------------


def test_srgb_spot_values_and_round_trip():
    # IEC 61966-2-1: the linear segment ends at 0.0031308 <-> 0.04045; 1 <-> 1
    np.testing.assert_allclose(
        linear_to_srgb([0.0, 0.0031308, 1.0]), [0.0, 0.04045, 1.0], atol=2e-6
    )
    # the example: an sRGB-decoding viewer shows byte-encoded 0.512 as 0.2253
    np.testing.assert_allclose(srgb_to_linear(0.512), ((0.512 + 0.055) / 1.055) ** 2.4)
    x = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(srgb_to_linear(linear_to_srgb(x)), x, atol=1e-12)
    # 8-bit: what Blender/MeshLab decode is within one sRGB step of the linear value
    shown = srgb_to_linear(srgb_bytes(x) / 255.0)
    step = srgb_to_linear(np.minimum(linear_to_srgb(x) + 0.5 / 255, 1)) - x
    assert (np.abs(shown - x) <= step + 1e-12).all()
    assert np.abs(shown - x).max() < 0.0045  # half an sRGB step near white: 0.5 / 255 * 2.2


def test_quantize_is_normalised_rounding():
    np.testing.assert_array_equal(quantize([0, 0.5, 1], np.uint8), [0, 128, 255])
    np.testing.assert_array_equal(quantize([0, 0.5, 1], np.uint16), [0, 32768, 65535])
    assert quantize([0.25], np.float32).dtype == np.float32


# -- PLY written back whole ----------------------------------------------------------------


def _rich_ply(path, *, text=True, alpha=True, colours=True):
    """A tetrahedron with double positions, uv, colours, a custom short, a face flag and an
    extra element (edges with lists of two lengths)."""
    fields = [("x", "f8"), ("y", "f8"), ("z", "f8"), ("s", "f4"), ("t", "f4")]
    if colours:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")] + (
            [("alpha", "u1")] if alpha else []
        )
    fields += [("label", "i2")]
    v = np.zeros(4, dtype=fields)
    v["x"], v["y"], v["z"] = [0, 1.1, 0, 0], [0, 0, 1.3, 0], [0, 0, 0, 1.7]
    v["s"], v["t"] = [0.1, 0.3, 0.5, 0.7], [0.2, 0.4, 0.6, 0.8]
    if colours:
        v["red"], v["green"], v["blue"] = [10, 50, 90, 1], [20, 60, 100, 2], [30, 70, 110, 3]
        if alpha:
            v["alpha"] = [40, 80, 120, 4]
    v["label"] = [7, -8, 9, 5]
    f = np.array(
        [([0, 2, 1], 1), ([0, 1, 3], 2), ([0, 3, 2], 3), ([1, 2, 3], 4)],
        dtype=[("vertex_indices", "i4", (3,)), ("flag", "u1")],
    )
    e = np.empty(2, dtype=[("ends", object)])
    e["ends"] = [np.array([0, 1], "i4"), np.array([1, 2, 3], "i4")]
    elements = [
        PlyElement.describe(v, "vertex"),
        PlyElement.describe(f, "face"),
        PlyElement.describe(e, "path"),
    ]
    PlyData(elements, text=text, comments=["made by a test", "aobake method=old"]).write(str(path))
    return v, f


AO = np.array([0.0, 0.25, 0.5, 1.0])


@pytest.mark.parametrize("text", [True, False])
def test_ply_keeps_every_element_and_property(tmp_path, text):
    v, f = _rich_ply(tmp_path / "in.ply", text=text)
    surface = load_mesh(tmp_path / "in.ply")
    write_bake(tmp_path / "out.ply", surface, AO, custom_data={"method": "embree"}, up_axis="Z")
    out = PlyData.read(str(tmp_path / "out.ply"))
    vertex = out["vertex"]
    assert [p.name for p in vertex.properties] == list(v.dtype.names) + ["ao", "quality"]
    for name in v.dtype.names:  # values and types as the input's
        assert vertex.data[name].dtype == v.dtype[name], name
        np.testing.assert_array_equal(vertex.data[name], v[name])
    np.testing.assert_array_equal(vertex.data["ao"], AO.astype(np.float32))
    np.testing.assert_array_equal(np.stack(out["face"].data["vertex_indices"]), f["vertex_indices"])
    np.testing.assert_array_equal(out["face"].data["flag"], f["flag"])
    assert [list(x) for x in out["path"].data["ends"]] == [[0, 1], [1, 2, 3]]
    assert out.comments == [
        "made by a test",
        "aobake method=embree",
        "aobake up_axis=Z",
        "aobake meters_per_unit=1",
    ]
    # read back by aobake: the recorded up axis and the same ao
    again = load_mesh(tmp_path / "out.ply")
    assert again.metadata["up_axis"] == "Z" and again.metadata["meters_per_unit"] == 1.0
    np.testing.assert_array_equal(read_bake(tmp_path / "out.ply"), AO)


def test_ply_rebake_replaces_ao_in_place(tmp_path):
    _rich_ply(tmp_path / "in.ply")
    write_bake(tmp_path / "a.ply", load_mesh(tmp_path / "in.ply"), AO)
    write_bake(tmp_path / "b.ply", load_mesh(tmp_path / "a.ply"), AO[::-1])
    names = [p.name for p in PlyData.read(str(tmp_path / "b.ply"))["vertex"].properties]
    assert names.count("ao") == 1 and names[-2:] == ["ao", "quality"]
    np.testing.assert_array_equal(read_bake(tmp_path / "b.ply"), AO[::-1])


def test_ply_color_is_srgb_and_replaces_rgb_keeping_alpha(tmp_path):
    v, _ = _rich_ply(tmp_path / "in.ply")
    write_bake(tmp_path / "out.ply", load_mesh(tmp_path / "in.ply"), AO, color=True)
    data = PlyData.read(str(tmp_path / "out.ply"))["vertex"].data
    for name in ("red", "green", "blue"):
        # decoded as Blender and MeshLab do (sRGB bytes -> linear): the linear ao
        np.testing.assert_allclose(srgb_to_linear(data[name] / 255.0), AO, atol=0.0045)
    np.testing.assert_array_equal(data["alpha"], v["alpha"])
    # the same grey as USD's linear displayColor
    np.testing.assert_array_equal(data["red"], [0, 137, 188, 255])


@pytest.mark.parametrize("channel", ["R", "G", "B", "A"])
def test_ply_channel_packs_linear_ao_and_keeps_other_channels(tmp_path, channel):
    v, _ = _rich_ply(tmp_path / "in.ply", text=False)
    write_bake(tmp_path / "out.ply", load_mesh(tmp_path / "in.ply"), AO, channel=channel)
    data = PlyData.read(str(tmp_path / "out.ply"))["vertex"].data
    target = {"R": "red", "G": "green", "B": "blue", "A": "alpha"}[channel]
    for name in ("red", "green", "blue", "alpha"):
        assert data[name].dtype == np.uint8
        if name == target:
            np.testing.assert_array_equal(data[name], np.rint(AO * 255))  # linear, not sRGB
        else:
            np.testing.assert_array_equal(data[name], v[name])


def test_ply_channel_a_adds_alpha_to_rgb(tmp_path):
    v, _ = _rich_ply(tmp_path / "in.ply", alpha=False)
    write_bake(tmp_path / "out.ply", load_mesh(tmp_path / "in.ply"), AO, channel="A")
    data = PlyData.read(str(tmp_path / "out.ply"))["vertex"].data
    np.testing.assert_array_equal(data["alpha"], [0, 64, 128, 255])
    np.testing.assert_array_equal(data["red"], v["red"])


def test_cli_channel_without_colours_is_one_line_error(tmp_path):
    _rich_ply(tmp_path / "in.ply", colours=False)
    out = tmp_path / "out.ply"
    result = CliRunner().invoke(
        main, ["bake", str(tmp_path / "in.ply"), "-o", str(out), "--rays", "4", "--channel", "A"]
    )
    assert result.exit_code == 1
    assert (
        result.output.strip()
        == "Error: in.ply: --channel A: the mesh has no vertex colours (red green blue)"
    )
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["in.ply"]


def test_cli_color_and_channel_together_is_a_usage_error(tmp_path):
    _rich_ply(tmp_path / "in.ply")
    result = CliRunner().invoke(
        main,
        [
            "bake",
            str(tmp_path / "in.ply"),
            "-o",
            str(tmp_path / "o.ply"),
            "--color",
            "--channel",
            "R",
        ],
    )
    assert result.exit_code == 2 and "--color and --channel" in result.output


def test_channel_to_usd_is_refused_before_baking(tmp_path):
    _rich_ply(tmp_path / "in.ply")
    result = CliRunner().invoke(
        main, ["bake", str(tmp_path / "in.ply"), "-o", str(tmp_path / "o.usda"), "--channel", "R"]
    )
    assert result.exit_code == 1 and "--channel is not written to USD" in result.output
    assert not (tmp_path / "o.usda").exists()


# -- up axis ---------------------------------------------------------------------------------


def test_preview_honours_the_recorded_up_axis(tmp_path):
    s = scenes.box((1.0, 2.0, 3.0))
    ao = np.linspace(0, 1, s.n_vertices)
    write_bake(tmp_path / "z.ply", s, ao, up_axis="Z")
    preview_file(tmp_path / "z.ply", tmp_path / "z.png", size=48)
    write_bake(tmp_path / "y.ply", s, ao, up_axis="Y")
    preview_file(tmp_path / "y.ply", tmp_path / "y.png", size=48)
    assert (tmp_path / "z.png").read_bytes() != (tmp_path / "y.png").read_bytes()
    from aobake.tools.preview import grey, png_bytes

    z_up = render_values(s.positions, s.faces, ao, size=48, up="Z")
    assert (tmp_path / "z.png").read_bytes() == png_bytes(grey(z_up))


# -- weld ------------------------------------------------------------------------------------


def _soup():
    """A sphere on a ground grid as a triangle soup (every triangle its own 3 vertices)."""
    s = scenes.combine_meshes(scenes.icosphere(1), scenes.ground_grid(2.0, 3, -1.0))
    corners = s.faces.reshape(-1)
    return s.positions[corners], np.arange(len(corners)).reshape(-1, 3)


def test_weld_vertices_merges_within_parts_in_first_occurrence_order():
    s = scenes.combine_meshes(_soup(), scenes.icosphere(0, center=(0, 0, 3)))
    welded, inverse = weld_vertices(s)
    np.testing.assert_array_equal(welded.positions[inverse], s.positions)
    icosphere_vertices = len(scenes.icosphere(1)[0]) + 16 + 12
    assert welded.n_vertices == icosphere_vertices
    # first occurrences in input order: the first welded vertex of each part is its first
    first = np.unique(inverse, return_index=True)[1]
    assert (np.diff(first) > 0).all()
    np.testing.assert_array_equal(welded.faces, inverse[s.faces])
    assert [p.n_vertices for p in welded.parts] == [len(scenes.icosphere(1)[0]) + 16, 12]


def test_weld_equals_the_bake_of_the_welded_mesh(tmp_path):
    import trimesh

    positions, faces = _soup()
    trimesh.Trimesh(positions, faces, process=False).export(tmp_path / "soup.stl")
    soup = load_mesh(tmp_path / "soup.stl")
    welded, inverse = weld_vertices(soup)
    write_bake(tmp_path / "welded.ply", welded, np.ones(welded.n_vertices))  # positions, no normals
    plain = PlyData.read(str(tmp_path / "welded.ply"))
    v = plain["vertex"].data
    bare = np.zeros(len(v), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    for k in "xyz":
        bare[k] = v[k]
    PlyData([PlyElement.describe(bare, "vertex"), plain["face"]]).write(
        str(tmp_path / "welded_bare.ply")
    )
    opts = dict(n_rays=32, seed=5, threads=1)
    bake_file(tmp_path / "soup.stl", tmp_path / "soup_ao.ply", weld=True, **opts)
    bake_file(tmp_path / "welded_bare.ply", tmp_path / "welded_ao.ply", **opts)
    got, ref = read_bake(tmp_path / "soup_ao.ply"), read_bake(tmp_path / "welded_ao.ply")
    assert got.shape == (len(positions),)
    np.testing.assert_array_equal(got, ref[inverse])
    assert ref.min() < 0.9  # the ground under the sphere is occluded: not a trivial bake


def test_weld_and_color_reach_every_output_format(tmp_path):
    import trimesh

    positions, faces = _soup()
    trimesh.Trimesh(positions, faces, process=False).export(tmp_path / "soup.stl")
    outputs = [tmp_path / "o.ply", tmp_path / "o.usda", tmp_path / "o.glb", tmp_path / "o.gltf"]
    bake_file(tmp_path / "soup.stl", outputs, weld=True, color=True, n_rays=16, seed=1, threads=1)
    values = [read_bake(p) for p in outputs]
    for v in values[1:]:
        np.testing.assert_array_equal(v, values[0])
    # the copies of a welded vertex carry one value
    _, inverse = np.unique(positions.astype(np.float32), axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    for k in range(inverse.max() + 1):
        assert np.ptp(values[0][inverse == k]) == 0
    assert np.unique(inverse).size < len(positions) / 4


def test_channel_for_an_input_without_kept_colours_is_refused_before_baking(tmp_path):
    import trimesh

    trimesh.Trimesh(*_soup(), process=False).export(tmp_path / "soup.stl")
    for out in ("o.ply", "o.glb"):
        result = CliRunner().invoke(
            main, ["bake", str(tmp_path / "soup.stl"), "-o", str(tmp_path / out), "--channel", "B"]
        )
        assert result.exit_code == 1
        assert (
            result.output
            == "Error: soup.stl: --channel B: the mesh has no vertex colours to write into\n"
        )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["soup.stl"]


def test_ply_to_gltf_carries_uvs_and_colours(tmp_path):
    import gltf_assets as ga

    v, _ = _rich_ply(tmp_path / "in.ply")
    surface = load_mesh(tmp_path / "in.ply")
    write_bake(tmp_path / "o.glb", surface, AO)
    write_bake(tmp_path / "g.glb", surface, AO, channel="G")
    gl, blobs = ga.load(tmp_path / "o.glb")
    attributes = gl["meshes"][0]["primitives"][0]["attributes"]
    uv = ga.accessor(gl, blobs, attributes["TEXCOORD_0"])
    np.testing.assert_array_equal(
        uv, np.c_[v["s"], 1.0 - v["t"].astype(np.float64)].astype(np.float32)
    )
    colors = ga.accessor(gl, blobs, attributes["COLOR_0"])  # linear floats: what viewers showed
    rgb = np.c_[v["red"], v["green"], v["blue"]] / 255.0
    np.testing.assert_allclose(
        colors[:, :3],
        ((rgb + 0.055) / 1.055) ** 2.4 * (rgb > 0.04045) + rgb / 12.92 * (rgb <= 0.04045),
        rtol=1e-6,
    )
    np.testing.assert_allclose(colors[:, 3], v["alpha"] / 255.0, rtol=1e-6)
    np.testing.assert_array_equal(
        ga.accessor(gl, blobs, attributes["_AO"])[:, 0], AO.astype(np.float32)
    )
    gl, blobs = ga.load(tmp_path / "g.glb")
    index = gl["meshes"][0]["primitives"][0]["attributes"]["COLOR_0"]
    packed = ga.accessor(gl, blobs, index)
    assert packed.dtype == np.uint8 and gl["accessors"][index]["normalized"] is True
    np.testing.assert_array_equal(packed, np.c_[v["red"], np.rint(AO * 255), v["blue"], v["alpha"]])


@settings(max_examples=20, deadline=None)
@given(st.data())
def test_kept_elements_round_trip_any_types_and_list_lengths(tmp_path_factory, data):
    """Random extra elements (scalars of every PLY type, lists of varying lengths) come back
    from plyfile as written, beside a fixed tetrahedron."""
    types = ["i1", "u1", "i2", "u2", "i4", "u4", "f4", "f8"]
    rows = data.draw(st.integers(0, 6))
    scalar = data.draw(st.sampled_from(types))
    item = data.draw(st.sampled_from(types))
    counter = data.draw(st.sampled_from(["u1", "u2", "i4"]))
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    lengths = rng.integers(0, 5, rows)
    extra = np.empty(rows, dtype=[("k", scalar), ("items", object)])
    extra["k"] = (rng.integers(0, 100, rows)).astype(scalar)
    for r in range(rows):
        extra["items"][r] = rng.integers(0, 100, lengths[r]).astype(item)
    d = tmp_path_factory.mktemp("ply")
    v, f = _rich_ply(d / "base.ply", text=False)
    base = PlyData.read(str(d / "base.ply"))
    element = PlyElement.describe(
        extra, "extra", len_types={"items": counter}, val_types={"items": item}
    )
    PlyData([base["vertex"], base["face"], element], text=data.draw(st.booleans())).write(
        str(d / "in.ply")
    )
    write_bake(d / "out.ply", load_mesh(d / "in.ply"), AO)
    out = PlyData.read(str(d / "out.ply"))
    assert out["extra"].count == rows
    np.testing.assert_array_equal(out["extra"].data["k"], extra["k"])
    for r in range(rows):
        np.testing.assert_array_equal(out["extra"].data["items"][r], extra["items"][r])
    assert out["extra"].data["k"].dtype == np.dtype(scalar)  # the type kept, not widened
