"""Reading a scene's light: UsdLux, KHR_lights_punctual, MTL, PLY colours and --light,
each quantity against the value the format's own definition gives by hand."""

from __future__ import annotations

import base64
import json
import math
from pathlib import Path

import numpy as np
import pytest

from aobake.errors import InputError
from aobake.io import load_mesh
from aobake.io.lights import parse_light_spec, read_shading
from aobake.shading import DEFAULT_ALBEDO

pxr = pytest.importorskip("pxr")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade  # noqa: E402

# -- USD helpers --------------------------------------------------------------------------


def _stage(tmp_path, name="scene.usda"):
    path = tmp_path / name
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    return stage, path


def _quads(stage, where="/World/ground", n=2):
    """n unit quads side by side along x, in the z = 0 plane, facing +z."""
    mesh = UsdGeom.Mesh.Define(stage, where)
    points = []
    for k in range(n + 1):
        points += [(k, 0, 0), (k, 1, 0)]
    counts, indices = [], []
    for k in range(n):
        counts.append(4)
        indices += [2 * k, 2 * k + 2, 2 * k + 3, 2 * k + 1]
    mesh.CreatePointsAttr(points)
    mesh.CreateFaceVertexCountsAttr(counts)
    mesh.CreateFaceVertexIndicesAttr(indices)
    return mesh


def _material(stage, where, diffuse=None, emissive=None):
    material = UsdShade.Material.Define(stage, where)
    shader = UsdShade.Shader.Define(stage, f"{where}/surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    if diffuse is not None:
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*diffuse))
    if emissive is not None:
        shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*emissive))
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material, shader


def _bind(prim, material):
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(material)


def _read(stage, path, **kwargs):
    stage.GetRootLayer().Save()
    surface = load_mesh(path)
    return surface, read_shading(path, surface, **kwargs)


def _one_light(tmp_path, define, **kwargs):
    stage, path = _stage(tmp_path)
    _quads(stage)
    light = define(stage)
    _, shading = _read(stage, path, **kwargs)
    assert len(shading.lights) == 1
    return light, shading.lights[0]


# -- UsdLux -------------------------------------------------------------------------------


def test_rect_light_normalized_radiance_and_frame(tmp_path):
    def define(stage):
        light = UsdLux.RectLight.Define(stage, "/World/rect")
        light.CreateWidthAttr(2.0)
        light.CreateHeightAttr(3.0)
        light.CreateIntensityAttr(5.0)
        light.CreateExposureAttr(1.0)
        light.CreateNormalizeAttr(True)
        light.AddTranslateOp().Set(Gf.Vec3d(0.5, 0.5, 2.0))
        return light

    _, light = _one_light(tmp_path, define)
    assert light.kind == "rect" and light.name == "/World/rect"
    np.testing.assert_allclose(light.value, [5 * 2 / 6] * 3, rtol=1e-6)  # 5 * 2^1 / (2 * 3)
    np.testing.assert_allclose(light.position, [0.5, 0.5, 2.0])
    np.testing.assert_allclose(light.normal, [0, 0, -1], atol=1e-12)  # emits along -Z
    assert light.area == pytest.approx(6.0)
    assert {tuple(np.abs(light.u)), tuple(np.abs(light.v))} == {(1.0, 0, 0), (0, 1.5, 0)}
    assert light.shadow


def test_rect_light_rotated_and_scaled(tmp_path):
    # scale x by 2, then rotate 90 degrees about x: local -Z ends up along world +Y
    def define(stage):
        light = UsdLux.RectLight.Define(stage, "/World/rect")
        light.CreateIntensityAttr(8.0)
        light.CreateNormalizeAttr(True)
        light.AddRotateXOp().Set(90.0)
        light.AddScaleOp().Set(Gf.Vec3f(2.0, 1.0, 1.0))
        return light

    _, light = _one_light(tmp_path, define)
    np.testing.assert_allclose(light.normal, [0, 1, 0], atol=1e-9)
    assert light.area == pytest.approx(2.0)  # 1 x 1, x scaled by 2
    np.testing.assert_allclose(light.value, [4.0] * 3, rtol=1e-6)  # 8 / 2
    assert sorted([np.linalg.norm(light.u), np.linalg.norm(light.v)]) == pytest.approx([0.5, 1.0])


def test_rect_light_unnormalized_keeps_radiance(tmp_path):
    def define(stage):
        light = UsdLux.RectLight.Define(stage, "/World/rect")
        light.CreateWidthAttr(4.0)
        light.CreateIntensityAttr(2.0)
        light.CreateColorAttr(Gf.Vec3f(1.0, 0.5, 0.25))
        return light

    _, light = _one_light(tmp_path, define)
    np.testing.assert_allclose(light.value, [2.0, 1.0, 0.5], rtol=1e-6)


def test_disk_light_scaled_uniformly(tmp_path):
    def define(stage):
        light = UsdLux.DiskLight.Define(stage, "/World/disk")
        light.CreateRadiusAttr(0.5)
        light.CreateIntensityAttr(3.0)
        light.CreateNormalizeAttr(True)
        light.AddTranslateOp().Set(Gf.Vec3d(0, 0, 4))
        light.AddScaleOp().Set(Gf.Vec3f(2.0, 2.0, 2.0))
        return light

    _, light = _one_light(tmp_path, define)
    assert light.kind == "disk"
    assert light.radius == pytest.approx(1.0)
    np.testing.assert_allclose(light.value, [3.0 / math.pi] * 3, rtol=1e-6)  # 3 / (pi 1^2)
    np.testing.assert_allclose(light.normal, [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(light.position, [0, 0, 4])


def test_disk_light_squashed_is_a_disk_of_the_same_area_with_a_note(tmp_path):
    stage, path = _stage(tmp_path)
    _quads(stage)
    light = UsdLux.DiskLight.Define(stage, "/World/disk")
    light.CreateRadiusAttr(1.0)
    light.AddScaleOp().Set(Gf.Vec3f(4.0, 1.0, 1.0))
    _, shading = _read(stage, path)
    assert shading.lights[0].radius == pytest.approx(2.0)  # pi * 4 * 1 = pi * 2^2
    assert any("ellipse" in note for note in shading.notes)


def test_sphere_light_area_and_normalize(tmp_path):
    def define(stage):
        light = UsdLux.SphereLight.Define(stage, "/World/sphere")
        light.CreateRadiusAttr(2.0)
        light.CreateIntensityAttr(10.0)
        light.CreateNormalizeAttr(True)
        return light

    _, light = _one_light(tmp_path, define)
    assert light.kind == "sphere" and light.radius == pytest.approx(2.0)
    np.testing.assert_allclose(light.value, [10.0 / (16 * math.pi)] * 3, rtol=1e-6)


def test_sphere_light_treat_as_point_keeps_its_power(tmp_path):
    def define(stage):
        light = UsdLux.SphereLight.Define(stage, "/World/bulb")
        light.CreateRadiusAttr(0.5)
        light.CreateIntensityAttr(4.0)
        light.CreateTreatAsPointAttr(True)
        light.AddTranslateOp().Set(Gf.Vec3d(1, 2, 3))
        return light

    _, light = _one_light(tmp_path, define)
    assert light.kind == "point"
    np.testing.assert_allclose(light.value, [4.0 * math.pi * 0.25] * 3, rtol=1e-6)  # I = L pi r^2
    np.testing.assert_allclose(light.position, [1, 2, 3])


def test_sphere_light_with_a_cone_is_a_spot(tmp_path):
    def define(stage):
        light = UsdLux.SphereLight.Define(stage, "/World/spot")
        light.CreateRadiusAttr(0.1)
        light.CreateTreatAsPointAttr(True)
        light.CreateIntensityAttr(100.0)
        light.CreateNormalizeAttr(True)
        shaping = UsdLux.ShapingAPI.Apply(light.GetPrim())
        shaping.CreateShapingConeAngleAttr(30.0)
        shaping.CreateShapingConeSoftnessAttr(0.5)
        light.AddRotateYOp().Set(90.0)  # -Z turns to -X
        return light

    _, light = _one_light(tmp_path, define)
    assert light.kind == "spot"
    np.testing.assert_allclose(light.value, [25.0] * 3, rtol=1e-6)  # normalized: L0 / 4
    assert light.cone_outer == pytest.approx(math.radians(30))
    assert light.cone_inner == pytest.approx(math.radians(15))
    np.testing.assert_allclose(light.direction, [-1, 0, 0], atol=1e-9)


def test_distant_light_conventions(tmp_path):
    stage, path = _stage(tmp_path)
    _quads(stage)
    sharp = UsdLux.DistantLight.Define(stage, "/World/sharp")
    sharp.CreateAngleAttr(0.0)
    sharp.CreateIntensityAttr(3.0)
    sharp.AddRotateXOp().Set(-90.0)  # shines along -Z rotated: towards -Y... light sits at +Y? no: see below
    wide = UsdLux.DistantLight.Define(stage, "/World/wide")
    wide.CreateAngleAttr(1.0)
    wide.CreateIntensityAttr(1000.0)
    normalized = UsdLux.DistantLight.Define(stage, "/World/normalized")
    normalized.CreateAngleAttr(1.0)
    normalized.CreateIntensityAttr(1000.0)
    normalized.CreateNormalizeAttr(True)
    _, shading = _read(stage, path)
    lights = {light.name: light for light in shading.lights}
    sharp_light = lights["/World/sharp"]
    # rotateX(-90) maps local +Z to world +Y: the light sits towards +Y
    np.testing.assert_allclose(sharp_light.direction, [0, 1, 0], atol=1e-9)
    np.testing.assert_allclose(sharp_light.value, [3.0] * 3)
    assert sharp_light.angle == 0.0
    theta = math.radians(0.5)
    np.testing.assert_allclose(lights["/World/wide"].value, [1000 * math.pi * math.sin(theta) ** 2] * 3, rtol=1e-6)
    assert lights["/World/wide"].angle == pytest.approx(math.radians(1.0))
    np.testing.assert_allclose(lights["/World/wide"].direction, [0, 0, 1])
    np.testing.assert_allclose(lights["/World/normalized"].value, [1000.0] * 3)


def test_distant_light_default_intensity_is_the_schema_fallback(tmp_path):
    _, light = _one_light(tmp_path, lambda stage: UsdLux.DistantLight.Define(stage, "/World/sun"))
    theta = math.radians(0.53 / 2)
    np.testing.assert_allclose(light.value, [50000 * math.pi * math.sin(theta) ** 2] * 3, rtol=1e-5)


def test_dome_light_colour_and_shadow_api(tmp_path):
    def define(stage):
        light = UsdLux.DomeLight.Define(stage, "/World/sky")
        light.CreateIntensityAttr(0.5)
        light.CreateColorAttr(Gf.Vec3f(1.0, 1.0, 2.0))
        light.CreateNormalizeAttr(True)  # ignored for domes
        UsdLux.ShadowAPI.Apply(light.GetPrim()).CreateShadowEnableAttr(False)
        return light

    _, light = _one_light(tmp_path, define)
    assert light.kind == "dome"
    np.testing.assert_allclose(light.value, [0.5, 0.5, 1.0])
    assert light.shadow is False


def test_colour_temperature(tmp_path):
    stage, path = _stage(tmp_path)
    _quads(stage)
    for name, kelvin in (("d65", 6500.0), ("warm", 3000.0)):
        light = UsdLux.SphereLight.Define(stage, f"/World/{name}")
        light.CreateEnableColorTemperatureAttr(True)
        light.CreateColorTemperatureAttr(kelvin)
        light.CreateIntensityAttr(2.0)
    _, shading = _read(stage, path)
    d65, warm = shading.lights
    np.testing.assert_allclose(d65.value, [2.0] * 3, rtol=1e-6)  # 6500 K is white
    assert warm.value[0] > warm.value[1] > warm.value[2]


def test_invisible_lights_and_scene_lights_off(tmp_path):
    stage, path = _stage(tmp_path)
    _quads(stage)
    UsdLux.SphereLight.Define(stage, "/World/on")
    UsdGeom.Imageable(UsdLux.SphereLight.Define(stage, "/World/off").GetPrim()).MakeInvisible()
    surface, shading = _read(stage, path)
    assert [light.name for light in shading.lights] == ["/World/on"]
    assert read_shading(path, surface, scene_lights=False).lights == ()


def test_light_read_at_the_surface_time(tmp_path):
    stage, path = _stage(tmp_path)
    mesh = _quads(stage)
    mesh.GetPointsAttr().Set(mesh.GetPointsAttr().Get(), 10.0)  # read at t = 10
    light = UsdLux.SphereLight.Define(stage, "/World/bulb")
    light.CreateIntensityAttr().Set(1.0, 0.0)
    light.CreateIntensityAttr().Set(7.0, 10.0)
    stage.GetRootLayer().Save()
    surface = load_mesh(path, time=10.0)
    np.testing.assert_allclose(read_shading(path, surface).lights[0].value, [7.0] * 3)


@pytest.mark.parametrize(
    ("author", "message"),
    [
        (lambda s: UsdLux.SphereLight.Define(s, "/World/l").CreateIntensityAttr(float("nan")), "/World/l: inputs:intensity is nan"),
        (lambda s: UsdLux.SphereLight.Define(s, "/World/l").CreateIntensityAttr(-1.0), "/World/l: negative inputs:intensity"),
        (lambda s: UsdLux.SphereLight.Define(s, "/World/l").CreateColorAttr(Gf.Vec3f(1, -0.5, 1)), "/World/l: negative inputs:color"),
        (lambda s: UsdLux.RectLight.Define(s, "/World/l").CreateWidthAttr(0.0), "/World/l: a RectLight of zero area"),
        (lambda s: UsdLux.DiskLight.Define(s, "/World/l").CreateRadiusAttr(0.0), "/World/l: a DiskLight of zero area"),
        (lambda s: UsdLux.SphereLight.Define(s, "/World/l").CreateRadiusAttr(0.0), "/World/l: a SphereLight of zero area"),
        (lambda s: UsdLux.CylinderLight.Define(s, "/World/l"), "/World/l: a CylinderLight light is not supported"),
        (lambda s: UsdLux.LightAPI.Apply(UsdGeom.Cube.Define(s, "/World/l").GetPrim()), "/World/l: a Cube light is not supported"),
        (lambda s: UsdLux.DistantLight.Define(s, "/World/l").CreateAngleAttr(200.0), "/World/l: inputs:angle 200 degrees"),
        (lambda s: UsdLux.DomeLight.Define(s, "/World/l").CreateTextureFileAttr("sky.exr"), "/World/l: a textured DomeLight (sky.exr) is not supported"),
    ],
)
def test_bad_usd_lights_are_one_line_naming_the_prim(tmp_path, author, message):
    stage, path = _stage(tmp_path)
    _quads(stage)
    author(stage)
    stage.GetRootLayer().Save()
    surface = load_mesh(path)
    with pytest.raises(InputError) as info:
        read_shading(path, surface)
    text = str(info.value)
    assert text.startswith("scene.usda: ") and message in text and "\n" not in text
    assert read_shading(path, surface, scene_lights=False).lights == ()  # the way out works


# -- USD surfaces -------------------------------------------------------------------------


def test_bound_material_diffuse_and_emission(tmp_path):
    stage, path = _stage(tmp_path)
    mesh = _quads(stage)
    material, _ = _material(stage, "/World/Looks/lamp", diffuse=(0.5, 0.25, 0.125), emissive=(2.0, 1.0, 0.0))
    _bind(mesh.GetPrim(), material)
    _, shading = _read(stage, path)
    np.testing.assert_allclose(shading.face_albedo, [[0.5, 0.25, 0.125]] * 4, rtol=1e-6)
    np.testing.assert_allclose(shading.vertex_albedo, [[0.5, 0.25, 0.125]] * 6, rtol=1e-6)
    np.testing.assert_allclose(shading.face_emission, [[2.0, 1.0, 0.0]] * 4)
    assert shading.has_emitters and shading.sources["albedo"] == "UsdPreviewSurface diffuseColor"
    assert shading.sources["emission"] == "UsdPreviewSurface emissiveColor"


def test_geom_subsets_bind_two_materials_per_face(tmp_path):
    stage, path = _stage(tmp_path)
    mesh = _quads(stage, n=2)  # quad 0 -> triangles 0, 1; quad 1 -> triangles 2, 3
    red, _ = _material(stage, "/World/Looks/red", diffuse=(0.8, 0.1, 0.1))
    blue, _ = _material(stage, "/World/Looks/blue", diffuse=(0.1, 0.1, 0.8), emissive=(0, 0, 3))
    binding = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    for name, faces, material in (("left", [0], red), ("right", [1], blue)):
        subset = binding.CreateMaterialBindSubset(name, faces, UsdGeom.Tokens.face)
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(material)
    binding.CreateMaterialBindSubset("unbound", [0], UsdGeom.Tokens.face)  # keeps what it had
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set([(1, 1, 1)])  # covered by the subsets
    _, shading = _read(stage, path)
    np.testing.assert_allclose(shading.face_albedo, [[0.8, 0.1, 0.1]] * 2 + [[0.1, 0.1, 0.8]] * 2, rtol=1e-6)
    np.testing.assert_allclose(shading.face_emission, [[0, 0, 0]] * 2 + [[0, 0, 3]] * 2)
    assert shading.sources["albedo"] == "UsdPreviewSurface diffuseColor"  # not the unused default
    # vertex 2 (1, 0, 0) is on one red triangle (0, 2, 3) and two blue ones (2, 4, 5), (2, 5, 3)
    np.testing.assert_allclose(shading.vertex_albedo[2], [(0.8 + 0.2) / 3, 0.1, (0.1 + 1.6) / 3], rtol=1e-6)
    np.testing.assert_allclose(shading.vertex_albedo[0], [0.8, 0.1, 0.1], rtol=1e-6)


def test_display_color_then_default(tmp_path):
    stage, path = _stage(tmp_path)
    coloured = _quads(stage, "/World/coloured", n=2)
    coloured.CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform).Set([(0.2, 0.4, 0.6), (1.5, 0.0, 0.0)])
    plain = _quads(stage, "/World/plain", n=1)
    plain.AddTranslateOp().Set(Gf.Vec3d(0, 0, 1))
    _, shading = _read(stage, path)
    np.testing.assert_allclose(shading.face_albedo[:4], [[0.2, 0.4, 0.6]] * 2 + [[1.0, 0, 0]] * 2, rtol=1e-6)
    np.testing.assert_allclose(shading.face_albedo[4:], DEFAULT_ALBEDO)
    assert any("clamped to 1" in note for note in shading.notes)
    assert shading.sources["albedo"].startswith("displayColor")


def test_primvar_reader_follows_to_vertex_colours(tmp_path):
    stage, path = _stage(tmp_path)
    mesh = _quads(stage, n=1)
    colours = [(0.0, 0.0, 0.0), (0.4, 0.4, 0.4), (0.8, 0.0, 0.0), (0.2, 0.2, 0.2)]  # per point
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex).Set(colours)
    material, shader = _material(stage, "/World/Looks/m")
    reader = UsdShade.Shader.Define(stage, "/World/Looks/m/reader")
    reader.CreateIdAttr("UsdPrimvarReader_float3")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("displayColor")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(reader.ConnectableAPI(), "result")
    _bind(mesh.GetPrim(), material)
    surface, shading = _read(stage, path)
    np.testing.assert_allclose(shading.vertex_albedo, colours, rtol=1e-6)
    expected = np.asarray(colours)[surface.faces].mean(axis=1)
    np.testing.assert_allclose(shading.face_albedo, expected, rtol=1e-6)


def test_textured_diffuse_is_a_note_and_the_default(tmp_path):
    stage, path = _stage(tmp_path)
    mesh = _quads(stage, n=1)
    material, shader = _material(stage, "/World/Looks/m")
    texture = UsdShade.Shader.Define(stage, "/World/Looks/m/tex")
    texture.CreateIdAttr("UsdUVTexture")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(texture.ConnectableAPI(), "rgb")
    _bind(mesh.GetPrim(), material)
    _, shading = _read(stage, path)
    np.testing.assert_allclose(shading.face_albedo, DEFAULT_ALBEDO)
    assert any("UsdUVTexture" in note for note in shading.notes)


def test_left_handed_mesh_face_varying_colours(tmp_path):
    stage, path = _stage(tmp_path)
    mesh = _quads(stage, n=1)
    mesh.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    corners = [(0.1, 0, 0), (0.2, 0, 0), (0.3, 0, 0), (0.4, 0, 0)]  # corners of [0, 2, 3, 1]
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.faceVarying).Set(corners)
    surface, shading = _read(stage, path)
    # reversed polygon [1, 3, 2, 0] fans (1, 3, 2), (1, 2, 0): corners (3, 2, 1) and (3, 1, 0)
    np.testing.assert_allclose(shading.face_albedo[:, 0], [(0.4 + 0.3 + 0.2) / 3, (0.4 + 0.2 + 0.1) / 3])
    np.testing.assert_array_equal(np.sort(surface.faces, axis=1), [[1, 2, 3], [0, 1, 2]])


def test_mesh_light_emits_from_its_triangles(tmp_path):
    stage, path = _stage(tmp_path)
    _quads(stage, "/World/ground", n=1)
    panel = _quads(stage, "/World/panel", n=2)  # area 2
    panel.AddTranslateOp().Set(Gf.Vec3d(0, 0, 3))
    UsdLux.MeshLightAPI.Apply(panel.GetPrim())
    light = UsdLux.LightAPI(panel.GetPrim())
    light.CreateIntensityAttr(6.0)
    light.CreateNormalizeAttr(True)
    _, shading = _read(stage, path)
    assert shading.lights == ()
    np.testing.assert_allclose(shading.face_emission[:2], 0.0)
    np.testing.assert_allclose(shading.face_emission[2:], 3.0)  # 6 / area 2
    assert shading.sources["emission"] == "MeshLightAPI"


# -- glTF ---------------------------------------------------------------------------------


def _gltf(tmp_path, *, lights=(), light_nodes=(), material=None, colours=None, name="scene.gltf"):
    """One triangle (z = 0, facing +z) under node 0; ``light_nodes`` are extra nodes
    (dicts) put under root node 1."""
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    blob = positions.tobytes()
    accessors = [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                  "min": [0, 0, 0], "max": [1, 1, 0]}]  # fmt: skip
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": len(blob)}]
    attributes = {"POSITION": 0}
    if colours is not None:
        data = np.asarray(colours, np.float32).tobytes()
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
        accessors.append({"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC3"})
        attributes["COLOR_0"] = 1
        blob += data
    primitive = {"attributes": attributes}
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"name": "tri", "mesh": 0}, {"name": "rig", "children": list(range(2, 2 + len(light_nodes))),
                                                "translation": [0, 0, 5]}, *light_nodes],  # fmt: skip
        "meshes": [{"primitives": [primitive]}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
    }  # fmt: skip
    if material is not None:
        doc["materials"] = [material]
        primitive["material"] = 0
    if lights:
        doc["extensions"] = {"KHR_lights_punctual": {"lights": list(lights)}}
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return path


def _gltf_shading(path, **kwargs):
    return read_shading(path, load_mesh(path), **kwargs)


def test_gltf_spot_under_a_parent_transform(tmp_path):
    half = math.sqrt(0.5)
    spot = {"type": "spot", "intensity": 40.0, "color": [1.0, 0.5, 0.25], "range": 12.0,
            "spot": {"innerConeAngle": 0.2, "outerConeAngle": 0.6}}  # fmt: skip
    node = {"name": "lamp", "translation": [1, 0, 0], "rotation": [half, 0, 0, half],  # 90 deg about x
            "scale": [3, 3, 3], "extensions": {"KHR_lights_punctual": {"light": 0}}}  # fmt: skip
    shading = _gltf_shading(_gltf(tmp_path, lights=[spot], light_nodes=[node]))
    (light,) = shading.lights
    assert light.kind == "spot" and light.name == "lamp"
    np.testing.assert_allclose(light.position, [1, 0, 5])  # parent translation + own
    np.testing.assert_allclose(light.direction, [0, 1, 0], atol=1e-9)  # -Z rotated about x by 90
    np.testing.assert_allclose(light.value, [40.0, 20.0, 10.0])  # candela, scale ignored
    assert (light.cone_inner, light.cone_outer, light.range) == (0.2, 0.6, 12.0)
    assert shading.sources["lights"] == "KHR_lights_punctual"


def test_gltf_directional_and_point_defaults(tmp_path):
    nodes = [{"extensions": {"KHR_lights_punctual": {"light": 0}}},
             {"name": "bulb", "translation": [0, 2, 0], "extensions": {"KHR_lights_punctual": {"light": 1}}}]  # fmt: skip
    lights = [{"type": "directional", "intensity": 3.0, "range": 1.0}, {"type": "point"}]
    sun, bulb = _gltf_shading(_gltf(tmp_path, lights=lights, light_nodes=nodes)).lights
    assert sun.kind == "distant" and sun.name == "node 2"
    np.testing.assert_allclose(sun.direction, [0, 0, 1])  # towards the light: against -Z
    np.testing.assert_allclose(sun.value, [3.0] * 3)  # lux
    assert sun.range == math.inf  # range applies to point and spot only
    np.testing.assert_allclose(bulb.value, [1.0] * 3)
    np.testing.assert_allclose(bulb.position, [0, 2, 5])
    assert bulb.range == math.inf


def test_gltf_materials(tmp_path):
    material = {"name": "glow", "pbrMetallicRoughness": {"baseColorFactor": [0.5, 1.0, 1.0, 1.0]},
                "emissiveFactor": [1.0, 0.5, 0.0],
                "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 4.0}}}  # fmt: skip
    colours = [[1.0, 0.2, 0.0], [0.0, 0.2, 1.0], [0.5, 0.5, 0.5]]
    shading = _gltf_shading(_gltf(tmp_path, material=material, colours=colours))
    vertex = np.asarray(colours) * [0.5, 1.0, 1.0]
    np.testing.assert_allclose(shading.vertex_albedo, vertex, rtol=1e-6)
    np.testing.assert_allclose(shading.face_albedo, [vertex.mean(axis=0)], rtol=1e-6)
    np.testing.assert_allclose(shading.face_emission, [[4.0, 2.0, 0.0]])
    assert shading.sources["albedo"] == "baseColorFactor x COLOR_0"
    assert shading.lights == ()  # no invented lights


def test_gltf_without_material_gets_the_default(tmp_path):
    shading = _gltf_shading(_gltf(tmp_path))
    np.testing.assert_allclose(shading.face_albedo, DEFAULT_ALBEDO)
    assert not shading.has_light


@pytest.mark.parametrize(
    ("light", "message"),
    [
        ({"type": "area"}, "unknown light type 'area'"),
        ({"type": "point", "intensity": float("nan")}, "intensity must be a finite number"),
        ({"type": "point", "intensity": -2}, "negative intensity"),
        ({"type": "point", "color": [1, -1, 1]}, "negative color"),
        ({"type": "point", "range": 0}, "range must be > 0"),
        ({"type": "spot", "spot": {"innerConeAngle": 0.5, "outerConeAngle": 0.4}}, "spot cone angles"),
    ],
)
def test_bad_gltf_lights(tmp_path, light, message):
    node = {"name": "lamp", "extensions": {"KHR_lights_punctual": {"light": 0}}}
    path = _gltf(tmp_path, lights=[light], light_nodes=[node])
    with pytest.raises(InputError) as info:
        _gltf_shading(path)
    assert str(info.value).startswith("scene.gltf: node 'lamp' (light 0)") and message in str(info.value)


def test_gltf_light_index_out_of_range(tmp_path):
    node = {"name": "lamp", "extensions": {"KHR_lights_punctual": {"light": 3}}}
    with pytest.raises(InputError, match=r"scene.gltf: node 'lamp': KHR_lights_punctual light 3 does not exist"):
        _gltf_shading(_gltf(tmp_path, lights=[{"type": "point"}], light_nodes=[node]))


# -- OBJ/MTL, PLY -------------------------------------------------------------------------


def test_obj_mtl_per_face(tmp_path):
    (tmp_path / "m.mtl").write_text(
        "newmtl red\nKd 0.8 0.1 0.1\n\nnewmtl lamp # a comment\nKd 0.5\nKe 2 2 1\n"
    )
    path = tmp_path / "m.obj"
    path.write_text(
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\n"
        "f 1 2 4\nusemtl red\nf 1 2 3 4\nusemtl lamp\nf 2 5 6 3\nusemtl missing\nf 2 5 6\n"
    )
    shading = _gltf_shading(path)
    np.testing.assert_allclose(
        shading.face_albedo,
        [[DEFAULT_ALBEDO] * 3, [0.8, 0.1, 0.1], [0.8, 0.1, 0.1], [0.5] * 3, [0.5] * 3, [DEFAULT_ALBEDO] * 3],
    )
    np.testing.assert_allclose(shading.face_emission[3:5], [[2, 2, 1]] * 2)
    np.testing.assert_allclose(shading.face_emission[[0, 1, 2, 5]], 0.0)
    assert any("'missing'" in note for note in shading.notes)
    assert shading.sources["emission"] == "MTL Ke"


def test_obj_bad_mtl(tmp_path):
    (tmp_path / "m.mtl").write_text("newmtl red\nKd spectral red.spd\n")
    path = tmp_path / "m.obj"
    path.write_text("mtllib m.mtl\nusemtl red\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(InputError, match=r"^m.mtl: line 2: Kd needs 1 or 3 numbers"):
        _gltf_shading(path)
    (tmp_path / "m.mtl").write_text("newmtl red\nKd 0.5 -0.1 0.5\n")
    with pytest.raises(InputError, match=r"^m.obj: material 'red': negative Kd"):
        _gltf_shading(path)


def _ply(tmp_path, colour_type, colours):
    rows = "\n".join(f"{x} {y} 0 {' '.join(str(c) for c in rgb)}" for (x, y), rgb in zip([(0, 0), (1, 0), (0, 1)], colours, strict=True))
    path = tmp_path / "c.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        f"property {colour_type} red\nproperty {colour_type} green\nproperty {colour_type} blue\n"
        f"element face 1\nproperty list uchar int vertex_indices\nend_header\n{rows}\n3 0 1 2\n"
    )
    return path


def test_ply_byte_colours_are_srgb(tmp_path):
    path = _ply(tmp_path, "uchar", [(255, 0, 188), (10, 128, 0), (0, 0, 0)])
    shading = _gltf_shading(path)

    def linear(byte):  # the sRGB decoding by hand
        s = byte / 255
        return s / 12.92 if s <= 0.04045 else ((s + 0.055) / 1.055) ** 2.4

    np.testing.assert_allclose(shading.vertex_albedo[0], [1.0, 0.0, linear(188)])
    np.testing.assert_allclose(shading.vertex_albedo[1], [linear(10), linear(128), 0.0])
    np.testing.assert_allclose(shading.face_albedo[0], shading.vertex_albedo.mean(axis=0))


def test_ply_float_colours_are_linear(tmp_path):
    shading = _gltf_shading(_ply(tmp_path, "float", [(0.5, 0.25, 0.0), (0.1, 0.2, 0.3), (0, 0, 0)]))
    np.testing.assert_allclose(shading.vertex_albedo[:2], [[0.5, 0.25, 0.0], [0.1, 0.2, 0.3]], rtol=1e-6)
    assert "linear" in shading.sources["albedo"]


def test_formats_without_colours_get_the_default(tmp_path):
    path = tmp_path / "t.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    )
    shading = _gltf_shading(path, cli_lights=["point:0,0,1:2"])
    np.testing.assert_allclose(shading.face_albedo, DEFAULT_ALBEDO)
    assert shading.sources == {"albedo": f"default {DEFAULT_ALBEDO}", "emission": "none", "lights": "--light"}
    assert shading.lights[0].name == "--light 1"


# -- --light ------------------------------------------------------------------------------


def test_light_specs():
    sun = parse_light_spec("distant:0,0,2:3:1,0.5,0", 1)
    assert sun.kind == "distant" and sun.name == "--light 1"
    np.testing.assert_allclose(sun.direction, [0, 0, 1])  # from the surface towards the light
    np.testing.assert_allclose(sun.value, [3.0, 1.5, 0.0])
    bulb = parse_light_spec("point:1,2,3", 2)
    assert bulb.kind == "point" and bulb.name == "--light 2"
    np.testing.assert_allclose(bulb.position, [1, 2, 3])
    np.testing.assert_allclose(bulb.value, [1.0] * 3)
    np.testing.assert_allclose(parse_light_spec("POINT:0,0,0:5", 3).value, [5.0] * 3)


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("spot:0,0,1", "unknown light kind 'spot'"),
        ("distant", "expected distant:DX,DY,DZ"),
        ("distant:0,0", "direction DX,DY,DZ must be 3 finite numbers"),
        ("distant:0,0,0", "the direction has zero length"),
        ("point:0,0,nan", "position X,Y,Z must be 3 finite numbers"),
        ("point:0,0,1:-1", "intensity and colour must be >= 0"),
        ("point:0,0,1:1:1,1", "colour R,G,B must be 3 finite numbers"),
        ("point:0,0,1:1:1,1,1:extra", "expected point:X,Y,Z"),
    ],
)
def test_bad_light_specs(spec, message):
    with pytest.raises(ValueError) as info:
        parse_light_spec(spec, 4)
    assert str(info.value).startswith(f"--light 4 {spec!r}: ") and message in str(info.value)


# -- USD: scenes as artists build them ----------------------------------------------------


def test_instanced_meshes_and_lights(tmp_path):
    stage, path = _stage(tmp_path)
    proto = UsdGeom.Xform.Define(stage, "/Proto")
    mesh = _quads(stage, "/Proto/tile", n=1)
    material, _ = _material(stage, "/Proto/Looks/m", diffuse=(0.3, 0.6, 0.9))
    _bind(mesh.GetPrim(), material)
    bulb = UsdLux.SphereLight.Define(stage, "/Proto/bulb")
    bulb.AddTranslateOp().Set(Gf.Vec3d(0.5, 0.5, 1))
    for k in range(2):
        instance = UsdGeom.Xform.Define(stage, f"/World/i{k}")
        instance.AddTranslateOp().Set(Gf.Vec3d(3 * k, 0, 0))
        instance.GetPrim().GetReferences().AddInternalReference(proto.GetPath())
        instance.GetPrim().SetInstanceable(True)
    surface, shading = _read(stage, path)
    assert len(surface.parts) == 3  # /Proto itself is a visible mesh too
    np.testing.assert_allclose(shading.face_albedo, [[0.3, 0.6, 0.9]] * 6, rtol=1e-6)
    positions = sorted(tuple(light.position) for light in shading.lights)
    assert positions == [(0.5, 0.5, 1.0), (0.5, 0.5, 1.0), (3.5, 0.5, 1.0)]


def test_legacy_unprefixed_light_attributes(tmp_path):
    stage, path = _stage(tmp_path)
    _quads(stage)
    light = UsdLux.SphereLight.Define(stage, "/World/old")
    light.GetPrim().CreateAttribute("intensity", Sdf.ValueTypeNames.Float).Set(9.0)
    light.GetPrim().CreateAttribute("color", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(1, 0, 0))
    _, shading = _read(stage, path)
    np.testing.assert_allclose(shading.lights[0].value, [9.0, 0.0, 0.0])


def test_light_with_a_non_finite_transform(tmp_path):
    stage, path = _stage(tmp_path)
    _quads(stage)
    UsdLux.SphereLight.Define(stage, "/World/l").AddTranslateOp().Set(Gf.Vec3d(0, float("nan"), 0))
    with pytest.raises(InputError, match=r"^scene.usda: /World/l: its transform is not finite$"):
        _read(stage, path)


def test_bundled_cornell_box():
    path = Path(__file__).resolve().parents[1] / "data" / "cornell_box.usda"
    surface = load_mesh(path)
    shading = read_shading(path, surface)
    (light,) = shading.lights
    assert light.kind == "rect" and light.name == "/World/light"
    np.testing.assert_allclose(light.value, [12.0, 12 * 0.88, 12 * 0.72], rtol=1e-6)
    np.testing.assert_allclose(light.normal, [0, -1, 0], atol=1e-9)  # shines down
    assert light.area == pytest.approx(0.09, rel=1e-6)
    part = {p.name: p for p in surface.parts}
    np.testing.assert_allclose(shading.face_albedo[part["left"].face_start], [0.63, 0.065, 0.05], rtol=1e-6)
    np.testing.assert_allclose(shading.face_albedo[part["right"].face_start], [0.14, 0.45, 0.091], rtol=1e-6)
    assert shading.notes == () and shading.reflects and not shading.has_emitters


def test_holes_and_a_mirroring_transform_keep_faces_and_colours_aligned(tmp_path):
    stage, path = _stage(tmp_path)
    mesh = _quads(stage, n=3)
    mesh.CreateHoleIndicesAttr([1])  # the middle quad gives no triangle
    mesh.AddScaleOp().Set(Gf.Vec3f(-1, 1, 1))  # mirrors: the reader flips the winding
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform).Set([(0.1, 0, 0), (0.5, 0, 0), (0.9, 0, 0)])
    surface, shading = _read(stage, path)
    assert surface.n_faces == 4
    np.testing.assert_allclose(shading.face_albedo[:, 0], [0.1, 0.1, 0.9, 0.9], rtol=1e-6)


def test_bad_primvar_count_names_the_prim(tmp_path):
    stage, path = _stage(tmp_path)
    mesh = _quads(stage, n=2)
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform).Set([(0.1, 0.1, 0.1)] * 3)
    with pytest.raises(InputError, match=r"^scene.usda: /World/ground: primvars:displayColor has 3 uniform values, expected 2$"):
        _read(stage, path)


def test_malformed_gltf_light_is_one_line(tmp_path):
    node = {"name": "lamp", "extensions": {"KHR_lights_punctual": {"light": 0}}}
    path = _gltf(tmp_path, lights=["point"], light_nodes=[node])
    with pytest.raises(InputError, match=r"^scene.gltf: cannot read its lights and materials: "):
        _gltf_shading(path)


def test_shading_follows_a_weld(tmp_path):
    from aobake.io.lights import welded_shading
    from aobake.mesh import weld_vertices

    path = tmp_path / "soup.ply"  # two triangles sharing an edge, stored as a soup
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\nproperty float z\n"
        "property float red\nproperty float green\nproperty float blue\n"
        "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0 0.2 0 0\n1 0 0 0.4 0 0\n0 1 0 0.6 0 0\n1 0 0 0.8 0 0\n1 1 0 1 0 0\n0 1 0 0 0 0\n3 0 1 2\n3 3 4 5\n"
    )
    surface = load_mesh(path)
    shading = read_shading(path, surface)
    welded, inverse = weld_vertices(surface)
    moved = welded_shading(shading, inverse)
    assert moved.vertex_albedo.shape == (4, 3)
    np.testing.assert_allclose(moved.vertex_albedo[:, 0], [0.2, 0.6, 0.3, 1.0], rtol=1e-6)  # (0.4+0.8)/2, (0.6+0)/2
    np.testing.assert_array_equal(moved.face_albedo, shading.face_albedo)


def test_ply_face_colours(tmp_path):
    path = tmp_path / "faces.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 2\nproperty list uchar int vertex_indices\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
        "0 0 0\n1 0 0\n1 1 0\n0 1 0\n2 0 0\n4 0 1 2 3 255 0 0\n3 1 4 2 0 0 255\n"
    )
    shading = _gltf_shading(path)
    np.testing.assert_allclose(shading.face_albedo, [[1, 0, 0], [1, 0, 0], [0, 0, 1]])  # quad: 2 triangles
    np.testing.assert_allclose(shading.vertex_albedo[0], [1, 0, 0])
    np.testing.assert_allclose(shading.vertex_albedo[4], [0, 0, 1])
    assert shading.sources["albedo"] == "PLY face colours (sRGB-encoded integers)"
