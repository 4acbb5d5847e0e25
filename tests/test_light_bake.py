"""The lit bake end to end (issue 15): what a bake writes for light in every format, read
back with plyfile, pxr and pygltflib and checked against values computed here, the plan
against the transport's own culling, --effects, --weld, --occluders, batch, determinism
and bad input. Few rays and small meshes: these check wiring, not accuracy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from aobake.cli import main
from aobake.io import load_mesh, read_bake
from aobake.io.color import srgb_to_linear
from aobake.testing import scenes

CORNELL = Path(__file__).resolve().parents[1] / "data" / "cornell_box.usda"
# cheap rays: wiring, not accuracy
FEW = ["--rays", "8", "--light-samples", "4", "--indirect-rays", "4"]
IRR = ("irradiance_r", "irradiance_g", "irradiance_b")


def _ok(runner, args):
    result = runner.invoke(main, [str(a) for a in args])
    assert result.exit_code == 0, (result.output, result.stderr, result.exception)
    return result


def _fail(runner, args, code=1):
    result = runner.invoke(main, [str(a) for a in args])
    assert result.exit_code == code, (result.output, result.exception)
    assert result.exception is None or isinstance(result.exception, SystemExit)
    return result


def _one_line(result, *parts):
    lines = [line for line in result.stderr.splitlines() if not line.startswith("compiling")]
    assert len(lines) == 1, result.stderr
    for p in parts:
        assert p in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def scene_ply(tmp_path) -> Path:
    """A sphere on a floor, no colours, no lights (+Z up)."""
    s, _ = scenes.sphere_on_ground(0.5, 1, gap=0.0, cells=4)
    path = tmp_path / "scene.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(path)
    return path


def _ply_columns(path, names):
    import plyfile

    v = plyfile.PlyData.read(str(path))["vertex"].data
    return np.stack([np.asarray(v[k], dtype=np.float64) for k in names], axis=1)


def _ply_names(path):
    import plyfile

    return plyfile.PlyData.read(str(path))["vertex"].data.dtype.names


def _ply_comments(path):
    import plyfile

    return plyfile.PlyData.read(str(path)).comments


def _usd_primvar(path, name):
    """A primvar of every baked mesh, flattened, in traversal order (None: none has it)."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    parts = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
        if pv and pv.HasValue():
            parts.append(np.asarray(pv.ComputeFlattened(), dtype=np.float64).reshape(len(pv.ComputeFlattened()), -1))
            assert pv.GetInterpolation() == UsdGeom.Tokens.vertex
    return np.concatenate(parts) if parts else None


def _usd_custom(path):
    """What the file records under "aobake": the layer's (overlays, copies) and each
    baked mesh's customData (aobake's own stage), one dict per place."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    layer = dict(stage.GetRootLayer().customLayerData.get("aobake", {}))
    meshes = [dict(p.GetCustomDataByKey("aobake") or {}) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    return [layer] if layer else meshes


def _cornell_albedo():
    """(n, 3) per-vertex albedo of the Cornell box from its bound UsdPreviewSurface,
    read here with pxr (not aobake's reader)."""
    from pxr import Usd, UsdGeom, UsdShade

    stage = Usd.Stage.Open(str(CORNELL))
    rows = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        shader = UsdShade.Shader(material.GetPrim().GetChild("surface"))
        colour = np.asarray(shader.GetInput("diffuseColor").Get(), dtype=np.float64)
        n = len(UsdGeom.Mesh(prim).GetPointsAttr().Get())
        rows.append(np.tile(colour, (n, 1)))
    return np.concatenate(rows)


def _lit(albedo, irradiance, exposure=0.0, emission=0.0):
    return np.clip((albedo * irradiance / np.pi + emission) * 2.0**exposure, 0.0, 1.0)


# -- a scene without light bakes today's AO ----------------------------------------------


@pytest.mark.parametrize("suffix", [".ply", ".usda", ".glb"])
def test_no_light_is_the_ao_bake_byte_for_byte(runner, scene_ply, tmp_path, suffix):
    auto, ao = tmp_path / f"auto{suffix}", tmp_path / f"ao{suffix}"
    _ok(runner, ["bake", scene_ply, "-o", auto, "--rays", "8", "-q", "--color"])
    _ok(runner, ["bake", scene_ply, "-o", ao, "--rays", "8", "-q", "--color", "--effects", "ao"])
    assert auto.read_bytes() == ao.read_bytes()
    assert b"irradiance" not in auto.read_bytes()


def test_plain_ply_bake_makes_no_shading(monkeypatch, scene_ply):
    # a PLY has no lights: an auto bake without --light reads no shading (its per-vertex
    # and per-face arrays cost ~150 bytes per vertex), while a --light still reads it
    from aobake import lighting

    def refuse(*args, **kwargs):
        raise AssertionError("shading read")

    monkeypatch.setattr(lighting, "read", refuse)
    surface = load_mesh(scene_ply)
    assert lighting.prepare(scene_ply, surface, "embree", {}) is None
    with pytest.raises(AssertionError, match="shading read"):
        lighting.prepare(scene_ply, surface, "embree", {}, lights=("point 0 0 3 10",))


def test_plan_of_a_scene_without_light(runner, scene_ply):
    r = _ok(runner, ["plan", scene_ply])
    assert "yes ao" in r.stdout and "no  direct" in r.stdout and "no lights or emitters" in r.stdout


# -- every format, every light option ------------------------------------------------------


def test_ply_irradiance_split_and_lit_colour(runner, scene_ply, tmp_path):
    """PLY: float32 irradiance_r/g/b = direct + indirect, the split terms, and --color as
    the sRGB bytes of clip(0.18 E / pi * 2^exposure) (a file without colours: 0.18 grey)."""
    out = tmp_path / "lit.ply"
    args = ["bake", scene_ply, "-o", out, *FEW, "-q", "--light", "distant:0.3,0.2,1:2:1,0.5,0.25"]
    _ok(runner, args + ["--split-irradiance", "--color", "--exposure", "1.5"])
    names = _ply_names(out)
    for n in IRR + ("irradiance_direct_r", "irradiance_indirect_b", "red", "green", "blue", "ao"):
        assert n in names
    import plyfile

    v = plyfile.PlyData.read(str(out))["vertex"].data
    assert v["irradiance_r"].dtype == np.float32 and v["red"].dtype == np.uint8
    e = _ply_columns(out, IRR)
    d = _ply_columns(out, [f"irradiance_direct_{c}" for c in "rgb"])
    i = _ply_columns(out, [f"irradiance_indirect_{c}" for c in "rgb"])
    np.testing.assert_allclose(e, d + i, rtol=1e-6, atol=1e-6)
    assert np.isfinite(e).all() and (e >= 0).all() and e.max() > 0
    # the light's colour shows in the ratio of the channels of the direct term
    lit_direct = d[:, 0] > 0
    np.testing.assert_allclose(d[lit_direct, 1] / d[lit_direct, 0], 0.5, rtol=1e-5)
    # an open floor vertex facing the distant light straight on gets E perp * cos
    mesh = load_mesh(scene_ply)
    direction = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])
    cos = mesh.normals @ direction
    ao = read_bake(out)
    # (no occluder between an upward vertex far from the sphere and the light)
    far = (np.linalg.norm(mesh.positions[:, :2], axis=1) > 1.7) & (ao > 0.999)
    assert far.any()
    np.testing.assert_allclose(d[far, 0], 2.0 * cos[far], rtol=1e-5)
    # --color: the lit colour from the read-back irradiance, as sRGB bytes
    colour = _ply_columns(out, ["red", "green", "blue"]) / 255.0
    want = _lit(0.18, e, exposure=1.5)
    np.testing.assert_allclose(srgb_to_linear(colour), want, atol=0.006)
    # the header records what was computed
    comments = "\n".join(_ply_comments(out))
    assert "effects=ao, direct, indirect" in comments and "exposure=1.5" in comments


def test_usd_new_file_from_obj_with_light(runner, scene_ply, tmp_path):
    obj = tmp_path / "scene.obj"
    trimesh.load(scene_ply, process=False).export(obj)
    out = tmp_path / "lit.usda"
    _ok(runner, ["bake", obj, "-o", out, *FEW, "-q", "--light", "point:0,0,3:5", "--color", "--split-irradiance"])
    e = _usd_primvar(out, "irradiance")
    d, i = _usd_primvar(out, "irradiance_direct"), _usd_primvar(out, "irradiance_indirect")
    assert e.shape == (len(read_bake(out)), 3)
    np.testing.assert_allclose(e, d + i, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(_usd_primvar(out, "displayColor"), _lit(0.18, e), atol=1e-6)
    custom = _usd_custom(out)[0]
    assert custom["effects"] == "ao, direct, indirect"
    assert custom["lights"] == "--light 1" or "1" in custom["lights"]


@pytest.fixture(scope="module")
def cornell_bakes(tmp_path_factory):
    """The Cornell box baked once to PLY, a USD overlay, a flattened copy and a .usdz."""
    from click.testing import CliRunner

    d = tmp_path_factory.mktemp("cornell")
    outs = {k: d / f"box{k}" for k in (".ply", ".usda", ".usdz")}
    copy = d / "copy.usdc"
    runner = CliRunner()
    args = ["bake", CORNELL, *(x for o in outs.values() for x in ("-o", o)), *FEW, "-q", "--color", "--exposure", "1"]
    _ok(runner, args)
    _ok(runner, ["bake", CORNELL, "-o", copy, "--no-overlay", *FEW, "-q", "--color", "--exposure", "1"])
    outs["copy"] = copy
    return outs


def test_cornell_lit_colour_in_every_usd_output(cornell_bakes):
    albedo = _cornell_albedo()
    e_ply = _ply_columns(cornell_bakes[".ply"], IRR)
    assert e_ply.shape == albedo.shape
    for key in (".usda", ".usdz", "copy"):
        e = _usd_primvar(cornell_bakes[key], "irradiance")
        # one computation, written to each file (float32 in each)
        np.testing.assert_allclose(e, e_ply, rtol=1e-6, atol=1e-7)
        colour = _usd_primvar(cornell_bakes[key], "displayColor")
        np.testing.assert_allclose(colour, _lit(albedo, e, exposure=1.0), atol=1e-6)
        custom = _usd_custom(cornell_bakes[key])
        assert custom and all(c.get("effects") == "ao, direct, indirect" for c in custom)
        assert all(c.get("lights") == "/World/light" for c in custom)
    # the PLY's colour bytes: sRGB of the same lit colour
    colour = srgb_to_linear(_ply_columns(cornell_bakes[".ply"], ["red", "green", "blue"]) / 255.0)
    np.testing.assert_allclose(colour, _lit(albedo, e_ply, exposure=1.0), atol=0.006)
    # the walls' colours bleed: the red wall is redder than it is green
    red_wall = (albedo[:, 0] > 0.6) & (albedo[:, 1] < 0.1)
    assert (colour[red_wall, 0] >= colour[red_wall, 1]).all()


def test_cornell_overlay_keeps_the_source(cornell_bakes):
    """The overlay holds the bake only: its layer sublayers the source, which is untouched."""
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(cornell_bakes[".usda"]))
    assert layer.subLayerPaths and "cornell_box.usda" in layer.subLayerPaths[0]
    text = layer.ExportToString()
    assert "RectLight" not in text and "irradiance" in text


def test_cornell_preview_of_the_lit_colour(runner, cornell_bakes, tmp_path):
    png = tmp_path / "box.png"
    _ok(runner, ["preview", cornell_bakes[".ply"], "--show", "color", "--view", "front", "--size", "64", "-o", png])
    from tests.test_preview import _decode_png

    img = _decode_png(png.read_bytes()).astype(int)
    # coloured, not grey: the walls show red and green
    assert (img[..., 0] - img[..., 1] > 40).any() and (img[..., 1] - img[..., 0] > 40).any()


# -- glTF: KHR_lights_punctual in, attributes and COLOR_0 out ----------------------------


def _with_lights(glb_in, glb_out, lights, light_nodes):
    """A copy of a .glb with KHR_lights_punctual lights on new root nodes (pygltflib)."""
    import pygltflib

    g = pygltflib.GLTF2.load(str(glb_in))
    g.extensions = {"KHR_lights_punctual": {"lights": lights}}
    g.extensionsUsed = sorted(set(g.extensionsUsed or []) | {"KHR_lights_punctual"})
    for k, node in enumerate(light_nodes):
        g.nodes.append(pygltflib.Node(name=node["name"], translation=node.get("translation"),
                                      rotation=node.get("rotation"),
                                      extensions={"KHR_lights_punctual": {"light": k}}))  # fmt: skip
        g.scenes[g.scene or 0].nodes.append(len(g.nodes) - 1)
    g.save(str(glb_out))
    return glb_out


# a point light above the sphere, a spot looking down at one side whose cone misses
# most of the floor, a directional light from a low angle, and a point light under the
# floor with a short range (in reach of nothing)
PUNCTUAL = [
    {"type": "point", "intensity": 8.0, "color": [1.0, 0.9, 0.8]},
    {"type": "spot", "intensity": 20.0, "spot": {"innerConeAngle": 0.1, "outerConeAngle": 0.3}},
    {"type": "directional", "intensity": 1.5},
    {"type": "point", "intensity": 5.0, "range": 0.5},
]
_HALF = float(np.sqrt(0.5))
PUNCTUAL_NODES = [
    {"name": "bulb", "translation": [0.0, 0.0, 2.0]},
    {"name": "spot", "translation": [1.0, 1.0, 1.5]},  # -Z: straight down (+Z up scene)
    {"name": "sun", "rotation": [_HALF, 0.0, 0.0, _HALF]},  # -Z turned about x: towards -Y
    {"name": "under", "translation": [0.0, 0.0, -3.0]},
]


@pytest.fixture
def lit_glb(runner, scene_ply, tmp_path):
    plain = tmp_path / "plain.glb"
    _ok(runner, ["bake", scene_ply, "-o", plain, "--rays", "4", "-q"])
    return _with_lights(plain, tmp_path / "lit.glb", PUNCTUAL, PUNCTUAL_NODES)


def _gltf_attribute(path, name):
    from aobake.io.gltf import accessor_values, as_float, read_document, scene_slots

    doc = read_document(path)
    rows = []
    for slot in scene_slots(doc):
        a = doc.json["meshes"][slot.mesh]["primitives"][slot.primitive]["attributes"][name]
        rows.append(as_float(accessor_values(doc, a), doc.json["accessors"][a].get("normalized", False)))
    return np.concatenate(rows)


def test_gltf_kept_with_punctual_lights(runner, lit_glb, tmp_path):
    import pygltflib

    out = tmp_path / "out.glb"
    _ok(runner, ["bake", lit_glb, "-o", out, *FEW, "-q", "--color", "--split-irradiance"])
    g = pygltflib.GLTF2.load(str(out))
    # the input's lights are kept as they were
    assert g.extensions["KHR_lights_punctual"]["lights"] == PUNCTUAL
    attrs = g.meshes[0].primitives[0].attributes
    present = {k for k, v in vars(attrs).items() if v is not None}
    assert {"_IRRADIANCE", "_IRRADIANCE_DIRECT", "_IRRADIANCE_INDIRECT", "COLOR_0", "_AO"} <= present
    e = _gltf_attribute(out, "_IRRADIANCE")
    d, i = _gltf_attribute(out, "_IRRADIANCE_DIRECT"), _gltf_attribute(out, "_IRRADIANCE_INDIRECT")
    np.testing.assert_allclose(e, d + i, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(_gltf_attribute(out, "COLOR_0")[:, :3], _lit(0.18, e), atol=1e-6)
    assert e.max() > 0 and np.isfinite(e).all()
    record = g.asset.extras["aobake"]
    assert record["effects"] == "ao, direct, indirect"
    assert record["lights"] == "bulb, spot, sun" and record["lights_skipped"] == "under"


def test_gltf_new_file_from_ply_with_light(runner, scene_ply, tmp_path):
    out = tmp_path / "new.glb"
    _ok(runner, ["bake", scene_ply, "-o", out, "-o", tmp_path / "new.ply", *FEW, "-q", "--color",
                 "--light", "point:0,0,2:8"])  # fmt: skip
    e = _gltf_attribute(out, "_IRRADIANCE")
    np.testing.assert_allclose(e, _ply_columns(tmp_path / "new.ply", IRR), rtol=1e-6)
    np.testing.assert_allclose(_gltf_attribute(out, "COLOR_0")[:, :3], _lit(0.18, e), atol=1e-6)


# -- the plan against the transport ---------------------------------------------------------


def _plan_reach(stdout):
    """light name -> receivers in reach (0 for a skipped light), from `aobake plan`."""
    out = {}
    for line in stdout.splitlines():
        line = line.strip()
        if line.startswith("light "):
            name = line.split()[1]
            out[name] = 0 if "skipped" in line else int(line.split(": ")[1].split()[0])
    return out


def _transport_stats(path, lights=()):
    from aobake.io.lights import read_shading
    from aobake.methods.embree.light import irradiance

    surface = load_mesh(path)
    shading = read_shading(path, surface, cli_lights=lights)
    result = irradiance(surface, shading, n_samples=2, bounces=0)
    return {s.name: s for s in result.lights}


@pytest.mark.parametrize("scene", ["cornell", "punctual"])
def test_plan_reach_equals_the_transports_culling(runner, scene, lit_glb):
    path = CORNELL if scene == "cornell" else lit_glb
    plan = _plan_reach(_ok(runner, ["plan", path]).stdout)
    stats = _transport_stats(path)
    n = load_mesh(path).n_vertices
    names = [k for k in stats if k != "emitters"]
    assert sorted(plan) == sorted(names)
    for name in names:
        assert plan[name] == n - stats[name].skipped, name
    if scene == "punctual":
        # every culling reason is exercised
        assert stats["spot"].cone > 0 and stats["under"].range > 0 and stats["sun"].behind > 0
        assert 0 < plan["spot"] < n and plan["under"] == 0


def test_plan_output(runner):
    r = _ok(runner, ["plan", CORNELL, "--light-samples", "4", "--indirect-rays", "2", "--rays", "8"])
    lines = r.stdout.splitlines()
    assert lines[0].startswith("cornell_box.usda: 1037 vertices")
    assert "yes ao" in r.stdout and "yes direct    the scene has 1 light" in r.stdout
    assert "yes indirect  1 bounce off albedo above zero" in r.stdout
    reach = _plan_reach(r.stdout)["/World/light"]
    assert f"{reach} receivers in reach, {4 * reach} shadow rays" in r.stdout
    # ao 1037 * 8, shadow 4 * reach, bounce 1037 * 2 * (1 + 1 light)
    ao, shadow, bounce = 1037 * 8, 4 * reach, 1037 * 2 * 2
    assert f"expected rays: {ao + shadow + bounce:,} (ao {ao:,}, shadow {shadow:,}, bounce {bounce:,})" in r.stdout
    r = _ok(runner, ["plan", CORNELL, "--effects", "ao"])
    assert "yes ao" in r.stdout and "no  direct    not asked for (--effects)" in r.stdout


# -- --effects, --bounces, --method ----------------------------------------------------------

LIGHT = ["--light", "point:0.4,0.3,1.6:6:1,0.8,0.6"]


def test_effects_ao_direct_is_the_direct_term_bit_for_bit(runner, scene_ply, tmp_path):
    split, direct, b0 = tmp_path / "split.ply", tmp_path / "direct.ply", tmp_path / "b0.ply"
    _ok(runner, ["bake", scene_ply, "-o", split, *FEW, "-q", *LIGHT, "--split-irradiance", "--seed", "3"])
    _ok(runner, ["bake", scene_ply, "-o", direct, *FEW, "-q", *LIGHT, "--effects", "ao,direct", "--seed", "3"])
    _ok(runner, ["bake", scene_ply, "-o", b0, *FEW, "-q", *LIGHT, "--bounces", "0", "--seed", "3"])
    d = _ply_columns(split, [f"irradiance_direct_{c}" for c in "rgb"])
    assert (_ply_columns(split, [f"irradiance_indirect_{c}" for c in "rgb"]) > 0).any()
    np.testing.assert_array_equal(_ply_columns(direct, IRR), d)
    np.testing.assert_array_equal(_ply_columns(b0, IRR), d)
    for path in (direct, b0):
        assert "aobake effects=ao, direct" in _ply_comments(path)
    # the AO is the AO of an unlit bake
    ao = tmp_path / "ao.ply"
    _ok(runner, ["bake", scene_ply, "-o", ao, *FEW, "-q", "--seed", "3"])
    np.testing.assert_array_equal(read_bake(ao), read_bake(direct))


def test_effects_the_scene_does_not_call_for_is_one_line(runner, scene_ply, tmp_path):
    out = tmp_path / "o.ply"
    r = _fail(runner, ["bake", scene_ply, "-o", out, "--rays", "4", "--effects", "ao,direct"])
    _one_line(r, "scene.ply", "--effects direct", "no lights or emitters")
    assert not out.exists()
    r = _fail(runner, ["bake", scene_ply, "-o", out, "--rays", "4", *LIGHT, "--effects", "ao,indirect"])
    _one_line(r, "scene.ply", "indirect needs direct")
    r = _fail(runner, ["bake", scene_ply, "-o", out, "--rays", "4", *LIGHT, "--bounces", "0", "--effects", "ao,direct,indirect"])
    _one_line(r, "scene.ply", "--bounces 0")
    assert not out.exists()


# -- --weld, --occluders -------------------------------------------------------------------


def test_weld_light_equals_the_welded_mesh(runner, scene_ply, tmp_path):
    """A soup (every triangle its own vertices) baked with --weld gets the light of the
    shared-vertex mesh: a distant light and no bounce are exact, whatever the vertex order."""
    mesh = trimesh.load(scene_ply, process=False)
    soup = tmp_path / "soup.ply"
    trimesh.Trimesh(mesh.vertices[mesh.faces.reshape(-1)], np.arange(mesh.faces.size).reshape(-1, 3),
                    process=False).export(soup)  # fmt: skip
    args = [*FEW, "-q", "--light", "distant:0.5,-0.3,1:3", "--bounces", "0"]
    _ok(runner, ["bake", soup, "-o", tmp_path / "w.ply", "--weld", *args])
    _ok(runner, ["bake", scene_ply, "-o", tmp_path / "m.ply", *args])
    welded = _ply_columns(tmp_path / "w.ply", IRR)
    direct = _ply_columns(tmp_path / "m.ply", IRR)
    np.testing.assert_allclose(welded, direct[mesh.faces.reshape(-1)], rtol=1e-5, atol=1e-6)
    assert direct.max() > 0 and (direct[:, 0] == 0).any()  # lit and shadowed vertices


def test_occluder_left_out_casts_no_shadow(runner, tmp_path):
    """--occluders without the tall block: the room's light is the light of the room
    without the block (the room's vertices come first: their samples line up)."""
    import shutil

    from pxr import Usd

    without = tmp_path / "without.usda"
    shutil.copy(CORNELL, without)  # (editing the bundled layer would change it for this process)
    stage = Usd.Stage.Open(str(without))
    stage.RemovePrim("/World/blocks/tall")
    stage.Save()
    args = [*FEW, "-q", "--bounces", "0"]
    occl = ["--occluders", "/World/box/*", "--occluders", "/World/blocks/short"]
    _ok(runner, ["bake", CORNELL, "-o", tmp_path / "o.ply", *args, *occl])
    _ok(runner, ["bake", without, "-o", tmp_path / "w.ply", *args])
    _ok(runner, ["bake", CORNELL, "-o", tmp_path / "all.ply", *args])
    n_room = sum(len(p.GetAttribute("points").Get()) for p in stage.Traverse() if p.GetPath().HasPrefix("/World/box") and p.GetTypeName() == "Mesh")
    o = _ply_columns(tmp_path / "o.ply", IRR)[:n_room]
    w = _ply_columns(tmp_path / "w.ply", IRR)[:n_room]
    everything = _ply_columns(tmp_path / "all.ply", IRR)[:n_room]
    np.testing.assert_array_equal(o, w)
    assert (o > everything).any() and (o >= everything).all()  # the tall block's shadow is gone


# -- batch -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def client():
    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address="127.0.0.1:0", silence_logs=50)
    c = Client(cluster)
    yield c
    c.close()
    cluster.close()


def test_batch_lit_input_equals_bake_and_split_refuses_it(runner, client, scene_ply, tmp_path):
    import shutil

    from aobake import batch

    lib = tmp_path / "lib"
    lib.mkdir()
    shutil.copy(CORNELL, lib / "cornell_box.usda")
    shutil.copy(scene_ply, lib / "scene.ply")
    options = {"n_rays": 8, "light_samples": 4, "indirect_rays": 4}
    settings = batch.Settings(options=options, color=True)
    r = batch.run_batch([lib], tmp_path / "out", formats=("ply", "usdc"), settings=settings, client=client)
    assert (r.done, r.failed) == (2, 0)
    for suffix in (".ply", ".usdc"):
        ref = tmp_path / f"ref{suffix}"
        _ok(runner, ["bake", lib / "cornell_box.usda", "-o", ref, *FEW, "-q", "--color"])
        if suffix == ".ply":
            assert (tmp_path / "out" / "cornell_box.ply").read_bytes() == ref.read_bytes()
        else:  # a flattened copy: same values (the layer records its own path)
            np.testing.assert_array_equal(_usd_primvar(tmp_path / "out" / "cornell_box.usdc", "irradiance"),
                                          _usd_primvar(ref, "irradiance"))  # fmt: skip
    # --split 2: the lit input fails with one line, the unlit one is baked
    r = batch.run_batch([lib], tmp_path / "split", formats=("ply",), settings=settings, client=client, split=2)
    status = {x["input"]: x for x in r.records}
    assert status["scene.ply"]["status"] == "done" and status["cornell_box.usda"]["status"] == "failed"
    error = status["cornell_box.usda"]["error"]
    assert "\n" not in error and "cornell_box.usda" in error and "split" in error
    assert not (tmp_path / "split" / "cornell_box.ply").exists()
    # --effects ao with --split: both baked, the AO of an unsplit bake
    ao = batch.Settings(options=options, effects=("ao",))
    r = batch.run_batch([lib], tmp_path / "ao", formats=("ply",), settings=ao, client=client, split=2)
    assert (r.done, r.failed) == (2, 0)
    _ok(runner, ["bake", lib / "cornell_box.usda", "-o", tmp_path / "ao.ply", *FEW, "-q", "--effects", "ao"])
    assert (tmp_path / "ao" / "cornell_box.ply").read_bytes() == (tmp_path / "ao.ply").read_bytes()


# -- determinism -------------------------------------------------------------------------------


def test_same_seed_same_irradiance_for_any_thread_count(runner, tmp_path):
    outs = []
    for threads in ("1", "2"):
        out = tmp_path / f"t{threads}.ply"
        _ok(runner, ["bake", CORNELL, "-o", out, *FEW, "-q", "--seed", "7", "--threads", threads, "--split-irradiance"])
        outs.append(out)
    assert outs[0].read_bytes() == outs[1].read_bytes()
    other = tmp_path / "s8.ply"
    _ok(runner, ["bake", CORNELL, "-o", other, *FEW, "-q", "--seed", "8"])
    assert not np.array_equal(_ply_columns(other, IRR), _ply_columns(outs[0], IRR))


# -- bad input through the CLI ----------------------------------------------------------------

QUAD_USDA = """#usda 1.0
(
    upAxis = "Z"
)
def Mesh "floor"
{{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
}}
{light}
"""


@pytest.mark.parametrize(
    "light, words",
    [
        ('def SphereLight "bulb"\n{\n float inputs:intensity = nan\n}', ["/bulb", "intensity"]),
        ('def DistantLight "sun"\n{\n color3f inputs:color = (1, -0.5, 1)\n}', ["/sun", "colo"]),
        ('def RectLight "panel"\n{\n float inputs:width = 0\n float inputs:height = 1\n}', ["/panel"]),
        ('def CylinderLight "tube"\n{\n float inputs:length = 1\n}', ["/tube", "CylinderLight"]),
    ],
    ids=["nan-intensity", "negative-colour", "zero-area-rect", "unknown-type"],
)
def test_bad_usd_light_is_one_line_and_no_output(runner, tmp_path, light, words):
    src = tmp_path / "scene.usda"
    src.write_text(QUAD_USDA.format(light=light))
    out = tmp_path / "out.ply"
    r = _fail(runner, ["bake", src, "-o", out, "-o", tmp_path / "out.usda", "--rays", "4"])
    _one_line(r, "scene.usda", *words)
    assert "Traceback" not in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.usda"]
    # aobake plan says the same
    r = _fail(runner, ["plan", src])
    _one_line(r, "scene.usda", *words)


@pytest.mark.parametrize(
    "spec",
    ["distnt:0,0,1", "point:0,0", "distant:0,0,1:nan", "point:0,0,1:1:1,-1,1", "distant:0,0,0"],
)
def test_bad_light_spec_is_a_usage_error(runner, scene_ply, tmp_path, spec):
    out = tmp_path / "o.ply"
    r = _fail(runner, ["bake", scene_ply, "-o", out, "--light", spec], code=2)
    assert "--light" in r.stderr and "Traceback" not in r.output
    assert not out.exists()


def test_lights_are_read_from_the_file_on_disk_not_a_stale_layer(runner, tmp_path):
    """A stage held open on the file (a host application, an earlier bake in this
    process) does not hide a rewrite from the light reader, as it does not from the
    mesh reader."""
    from pxr import Usd

    src = tmp_path / "scene.usda"
    src.write_text(QUAD_USDA.format(light='def DistantLight "sun"\n{\n float inputs:intensity = 2\n bool inputs:normalize = 1\n}'))
    held = Usd.Stage.Open(str(src))
    out = tmp_path / "o.ply"
    _ok(runner, ["bake", src, "-o", out, *FEW, "-q"])
    np.testing.assert_allclose(_ply_columns(out, IRR), 2.0, rtol=1e-6)  # open quad under the sun
    src.write_text(QUAD_USDA.format(light='def DistantLight "sun"\n{\n float inputs:intensity = 3\n bool inputs:normalize = 1\n}'))
    _ok(runner, ["bake", src, "-o", out, *FEW, "-q"])
    np.testing.assert_allclose(_ply_columns(out, IRR), 3.0, rtol=1e-6)
    assert held.GetPrimAtPath("/sun")  # (still held)


def test_obj_mtl_albedo_and_emission_in_the_lit_colour(runner, tmp_path):
    """OBJ/MTL: Kd is the albedo, Ke the emission of a panel facing the floor; the lit
    colour adds the panel's own emission, halved by --exposure -1."""
    (tmp_path / "s.mtl").write_text("newmtl floor\nKd 0.5 0.4 0.3\nnewmtl panel\nKd 0.2 0.2 0.2\nKe 0.3 0.25 0.2\n")
    (tmp_path / "s.obj").write_text(
        "mtllib s.mtl\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n"
        "v -0.5 -0.5 1\nv -0.5 0.5 1\nv 0.5 0.5 1\nv 0.5 -0.5 1\n"
        "g floor\nusemtl floor\nf 1 2 3 4\ng panel\nusemtl panel\nf 5 6 7 8\n"  # the panel faces -z
    )
    out = tmp_path / "o.usda"
    _ok(runner, ["bake", tmp_path / "s.obj", "-o", out, "-o", tmp_path / "o.ply", *FEW, "-q", "--color", "--exposure", "-1"])
    e = _usd_primvar(out, "irradiance")
    albedo = np.array([[0.5, 0.4, 0.3]] * 4 + [[0.2, 0.2, 0.2]] * 4)
    emission = np.array([[0.0] * 3] * 4 + [[0.3, 0.25, 0.2]] * 4)
    assert (e[:4] > 0).all()  # the floor is lit by the panel
    np.testing.assert_allclose(_usd_primvar(out, "displayColor"), _lit(albedo, e, -1.0, emission), atol=1e-6)
    colour = srgb_to_linear(_ply_columns(tmp_path / "o.ply", ["red", "green", "blue"]) / 255.0)
    np.testing.assert_allclose(colour, _lit(albedo, e, -1.0, emission), atol=0.004)
    custom = _usd_custom(out)[0]
    assert custom["emitting_triangles"] == 2 and custom["lights"] == "none" and custom["exposure"] == -1.0


def test_ground_occludes_a_lit_bake(runner, tmp_path):
    """--ground on a lit bake: a lamp under the plane lights the box's underside without
    it and nothing with it (shadow and bounce rays alike); the output records the plane."""
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    box.apply_translation((0.0, 0.0, 1.0))
    path = tmp_path / "box.ply"
    box.export(path)
    args = ["bake", path, *FEW, "-q", "--up", "Z", "--light", "point:0,0,-1:5"]
    _ok(runner, [*args, "-o", tmp_path / "open.ply"])
    _ok(runner, [*args, "-o", tmp_path / "ground.ply", "--ground", "0"])
    assert _ply_columns(tmp_path / "open.ply", IRR).max() > 0
    assert _ply_columns(tmp_path / "ground.ply", IRR).max() == 0
    assert any("ground=0" in c for c in _ply_comments(tmp_path / "ground.ply"))


def test_a_lit_embree_bake_builds_one_embree_scene(runner, scene_ply, tmp_path, monkeypatch):
    """The light pass traces the AO's Embree scene (one build, not two); outside a bake
    every call builds its own."""
    from aobake import tracing

    built = []
    real = tracing.Tracer.__init__

    def counting(self, *args, **kwargs):
        built.append(kwargs.get("robust", False))
        real(self, *args, **kwargs)

    monkeypatch.setattr(tracing.Tracer, "__init__", counting)
    _ok(runner, ["bake", scene_ply, "-o", tmp_path / "lit.ply", *FEW, "-q", "--light", "distant:0,0,1"])
    assert built.count(False) == 1  # (the contacts' robust local scenes aside)
    surface = load_mesh(scene_ply)
    assert tracing.tracer_for(surface.positions, surface.faces) is not tracing.tracer_for(surface.positions, surface.faces)
    with tracing.shared_scenes():
        assert tracing.tracer_for(surface.positions, surface.faces) is tracing.tracer_for(surface.positions, surface.faces)


def test_a_lit_usd_bake_opens_its_stage_once(tmp_path, monkeypatch):
    """Meshes, lights and materials come from one open stage (it was two)."""
    from pxr import Usd

    from aobake.pipeline import bake_file

    opened = []
    real = Usd.Stage.Open

    def counting(*args, **kwargs):
        opened.append(str(args[0]))
        return real(*args, **kwargs)

    monkeypatch.setattr(Usd.Stage, "Open", counting)
    bake_file(CORNELL, tmp_path / "o.ply", n_rays=4, light_samples=2, indirect_rays=2)
    assert len(opened) == 1 and opened[0].endswith("cornell_box.usda")
