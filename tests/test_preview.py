"""preview: the rasterizer (coverage, depth test, interpolation), PNG encoding, CLI."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from click.testing import CliRunner

from aobake.cli import main
from aobake.tools.preview import png_bytes, render_values


def _decode_png(data: bytes) -> np.ndarray:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, header = 8, b"", None
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + length]
        (crc,) = struct.unpack(">I", data[pos + 8 + length : pos + 12 + length])
        assert crc == zlib.crc32(kind + body) & 0xFFFFFFFF
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    w, h, _, colour, *_ = header
    channels = 3 if colour == 2 else 1
    raw = np.frombuffer(zlib.decompress(idat), dtype=np.uint8).reshape(h, 1 + w * channels)
    assert (raw[:, 0] == 0).all()  # filter type none
    return raw[:, 1:].reshape(h, w, channels)


def test_png_roundtrip_grey_and_rgb():
    img = np.linspace(0, 1, 12).reshape(3, 4)
    np.testing.assert_array_equal(_decode_png(png_bytes(img))[..., 0], np.round(img * 255))
    rgb = np.random.default_rng(0).random((5, 6, 3))
    np.testing.assert_array_equal(_decode_png(png_bytes(rgb)), np.round(rgb * 255))


def _quad(z, value):
    p = np.array([[-1, -1, z], [1, -1, z], [1, 1, z], [-1, 1, z]], dtype=float)
    return p, np.array([[0, 1, 2], [0, 2, 3]]), np.full(4, value)


def test_depth_test_keeps_the_nearer_surface():
    # Looking down -Z from above (up = Y, elevation 90 would be degenerate: use "top" with up Z)
    p0, f0, v0 = _quad(0.0, 0.2)
    p1, f1, v1 = _quad(0.5, 0.9)  # nearer to a camera above
    positions = np.vstack([p0, p1])
    faces = np.vstack([f0, f1 + 4])
    values = np.r_[v0, v1]
    img = render_values(positions, faces, values, size=64, up="Z", view="top")
    covered = ~np.isnan(img)
    assert covered.mean() > 0.2
    np.testing.assert_allclose(img[covered], 0.9)
    # swap draw order: same picture
    img2 = render_values(positions, np.vstack([f1 + 4, f0]), values, size=64, up="Z", view="top")
    np.testing.assert_array_equal(np.isnan(img), np.isnan(img2))
    np.testing.assert_allclose(img2[covered], 0.9)


def test_values_interpolate_between_vertices():
    p = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float)
    img = render_values(
        p,
        np.array([[0, 1, 2], [0, 2, 3]]),
        np.array([0.0, 1.0, 1.0, 0.0]),
        size=64,
        up="Z",
        view="top",
    )
    vals = img[~np.isnan(img)]
    assert vals.min() < 0.1 and vals.max() > 0.9
    assert 0.3 < vals.mean() < 0.7


@pytest.fixture
def baked(tmp_path):
    import trimesh

    from aobake.testing import scenes

    s, _ = scenes.sphere_on_ground(0.5, 2, cells=4)
    src = tmp_path / "s.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(src)
    out = tmp_path / "s_ao.ply"
    assert (
        CliRunner().invoke(main, ["bake", str(src), "-o", str(out), "--rays", "32", "-q"]).exit_code
        == 0
    )
    return out


def test_cli_preview(baked, tmp_path):
    png = tmp_path / "p.png"
    r = CliRunner().invoke(
        main, ["preview", str(baked), "-o", str(png), "--size", "96", "--up", "Z"]
    )
    assert r.exit_code == 0, r.output
    img = _decode_png(png.read_bytes())
    assert img.shape == (96, 96, 3)
    assert len(np.unique(img)) > 10  # shaded, not flat


def test_cli_preview_rejects_other_suffixes(baked, tmp_path):
    r = CliRunner().invoke(main, ["preview", str(baked), "-o", str(tmp_path / "p.jpg")])
    assert (
        r.exit_code == 1
        and r.stderr == "Error: p.jpg: previews are written as PNG; use a .png suffix\n"
    )


def test_cli_compare_render(baked, tmp_path):
    other = tmp_path / "o.usda"
    assert (
        CliRunner()
        .invoke(main, ["bake", str(baked), "-o", str(other), "--rays", "4", "-q"])
        .exit_code
        == 0
    )
    png = tmp_path / "c.png"
    r = CliRunner().invoke(main, ["compare", str(baked), str(other), "--render", str(png)])
    assert r.exit_code == 0, r.output
    img = _decode_png(png.read_bytes())
    assert img.shape[1] > 3 * img.shape[0]  # three panels side by side


# -- --show color: the vertex colours ----------------------------------------------------


def _colour_quad_ply(path, rgb_bytes, *, colours=True):
    import plyfile

    fields = [("x", "f4"), ("y", "f4"), ("z", "f4"), ("ao", "f4")]
    fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")] if colours else []
    v = np.zeros(4, dtype=fields)
    v["x"], v["y"], v["ao"] = [-1, 1, 1, -1], [-1, -1, 1, 1], 0.5
    if colours:
        v["red"], v["green"], v["blue"] = rgb_bytes
    f = np.zeros(2, dtype=[("vertex_indices", "i4", (3,))])
    f["vertex_indices"] = [[0, 1, 2], [0, 2, 3]]
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex"), plyfile.PlyElement.describe(f, "face")]).write(path)
    return path


def _centre(png_path):
    img = _decode_png(png_path.read_bytes())
    return img[img.shape[0] // 2, img.shape[1] // 2]


def test_show_color_ply_bytes_come_back(tmp_path):
    """PLY colour bytes are sRGB: decoded to linear, drawn sRGB-encoded, the same bytes."""
    src = _colour_quad_ply(tmp_path / "q.ply", (200, 40, 90))
    png = tmp_path / "q.png"
    args = ["preview", str(src), "-o", str(png), "--size", "32", "--up", "Z", "--view", "top"]
    r = CliRunner().invoke(main, args + ["--show", "color"])
    assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(_centre(png), [200, 40, 90])
    # the default stays the AO as grey (0.5 -> 128)
    assert CliRunner().invoke(main, args).exit_code == 0
    np.testing.assert_array_equal(_centre(png), [128, 128, 128])


def test_show_color_usd_display_color_and_gltf_color0(tmp_path):
    from pxr import Sdf, Usd, UsdGeom

    from aobake.io.color import linear_to_srgb

    linear = np.array([0.6, 0.05, 0.3])
    stage = Usd.Stage.CreateNew(str(tmp_path / "q.usda"))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    mesh = UsdGeom.Mesh.Define(stage, "/q")
    mesh.CreatePointsAttr([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    pv = UsdGeom.PrimvarsAPI(mesh)
    pv.CreatePrimvar("ao", Sdf.ValueTypeNames.FloatArray, "vertex").Set([0.5] * 4)
    mesh.CreateDisplayColorPrimvar("vertex").Set([tuple(linear)] * 4)
    stage.Save()
    png = tmp_path / "u.png"
    r = CliRunner().invoke(main, ["preview", str(tmp_path / "q.usda"), "-o", str(png), "--size", "32", "--view", "top", "--show", "color"])
    assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(_centre(png), np.round(linear_to_srgb(linear) * 255))
    # a PLY's colours kept in a glTF bake as linear COLOR_0 show the same bytes
    src = _colour_quad_ply(tmp_path / "c.ply", (10, 120, 250))
    glb = tmp_path / "c.glb"
    assert CliRunner().invoke(main, ["bake", str(src), "-o", str(glb), "--rays", "4", "-q"]).exit_code == 0
    r = CliRunner().invoke(main, ["preview", str(glb), "-o", str(png), "--size", "32", "--up", "Z", "--view", "top", "--show", "color"])
    assert r.exit_code == 0, r.output
    np.testing.assert_allclose(_centre(png), [10, 120, 250], atol=1)


def test_show_color_without_colours_is_one_line(tmp_path):
    src = _colour_quad_ply(tmp_path / "n.ply", None, colours=False)
    png = tmp_path / "n.png"
    r = CliRunner().invoke(main, ["preview", str(src), "-o", str(png), "--show", "color"])
    assert r.exit_code == 1
    assert r.stderr == "Error: n.ply: PLY vertices have no colours (red, green, blue) to show\n"
    assert not png.exists()
