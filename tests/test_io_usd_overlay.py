"""USD outputs of USD inputs: the overlay over the source, the flattened copy and the
.usdz package, read back through pxr.

The scenes are authored here with pxr: nested xforms, primvars:st, a textured material,
two meshes named ``box`` in different scopes, an invisible mesh, native instances and
time-sampled points. The ``ao`` in each output is checked against a plain bake of the same
world-space geometry built with numpy (not through USD's transform code).
"""

from __future__ import annotations

import shutil
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest

from aobake.cli import main
from aobake.io import load_mesh, read_bake
from aobake.mesh import surface_from_arrays
from aobake.methods.embree import embree_ao
from aobake.pipeline import bake_file

pxr = pytest.importorskip("pxr")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, UsdValidation, Vt  # noqa: E402

RAYS = 32
SEED = 3


# -- scenes ------------------------------------------------------------------------------


def _cube(lo, hi):
    """Points and outward quads of an axis-aligned box."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    points = np.array(
        [
            (x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
            (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1),
        ],
        dtype=np.float64,
    )
    quads = np.array(
        [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    )
    return points, quads


def _grid(half=2.0, cells=8, z=0.0):
    """A square of cells x cells quads in the plane z, facing +z."""
    t = np.linspace(-half, half, cells + 1)
    x, y = np.meshgrid(t, t, indexing="ij")
    points = np.c_[x.ravel(), y.ravel(), np.full(x.size, z)]
    i, j = np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij")
    a = (i * (cells + 1) + j).ravel()
    return points, np.c_[a, a + cells + 1, a + cells + 2, a + 1]


def _triangles(quads):
    return np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])


def _png(path: Path) -> None:
    """A 2x2 grey PNG (no imaging library needed)."""

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    raw = b"".join(b"\x00" + b"\x80\x80\x80" * 2 for _ in range(2))
    header = struct.pack(">IIBBBBB", 2, 2, 8, 2, 0, 0, 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
    )


def _mesh(stage, path, points, quads):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([4] * len(quads)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([int(k) for k in quads.ravel()]))
    mesh.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(mesh.GetPointsAttr().Get()))
    return mesh


def _material(stage):
    material = UsdShade.Material.Define(stage, "/World/Looks/Mat")
    surface = UsdShade.Shader.Define(stage, "/World/Looks/Mat/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    texture = UsdShade.Shader.Define(stage, "/World/Looks/Mat/Tex")
    texture.CreateIdAttr("UsdUVTexture")
    texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("tex/grid.png")
    rgb = texture.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    return material


def _scene(directory: Path, name="scene.usda") -> tuple[Path, np.ndarray, np.ndarray]:
    """A box (scaled, moved) resting on a rotated floor, both prims named ``box``.

    Returns the file and the world-space positions and triangles of the baked meshes
    in traversal order (/World/props/box, then /World/floor/box), computed with numpy.
    """
    _png(directory / "tex" / "grid.png")
    path = directory / name
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    stage.SetTimeCodesPerSecond(30)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    material = _material(stage)

    props = UsdGeom.Xform.Define(stage, "/World/props")
    props.AddTranslateOp().Set(Gf.Vec3d(0.5, 0.25, 0.0))
    props.AddScaleOp().Set(Gf.Vec3f(2.0, 2.0, 2.0))
    # 0.01 above the floor: a contact exactly in the floor's plane is ill-posed
    box_points, box_quads = _cube((-0.25, -0.25, 0.005), (0.25, 0.25, 0.5))
    box = _mesh(stage, "/World/props/box", box_points, box_quads)
    st = UsdGeom.PrimvarsAPI(box).CreatePrimvar(
        "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
    )
    st.Set(Vt.Vec2fArray([(0, 0), (1, 0), (1, 1), (0, 1)] * 6))
    UsdShade.MaterialBindingAPI.Apply(box.GetPrim()).Bind(material)

    floor = UsdGeom.Xform.Define(stage, "/World/floor")
    floor.AddRotateZOp().Set(90.0)
    floor_points, floor_quads = _grid()
    _mesh(stage, "/World/floor/box", floor_points, floor_quads)

    hidden = _mesh(stage, "/World/hidden", *_cube((5, 5, 5), (6, 6, 6)))
    hidden.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    stage.GetRootLayer().Save()
    del stage

    world_box = box_points * 2.0 + np.array([0.5, 0.25, 0.0])
    world_floor = np.c_[-floor_points[:, 1], floor_points[:, 0], floor_points[:, 2]]
    positions = np.vstack([world_box, world_floor])
    faces = np.vstack([_triangles(box_quads), _triangles(floor_quads) + len(box_points)])
    return path, positions, faces


def _plain_bake(positions, faces):
    return embree_ao(surface_from_arrays(positions, faces), n_rays=RAYS, seed=SEED).ao


def _bake(source, *outputs, **kwargs):
    return bake_file(source, list(outputs), method="embree", n_rays=RAYS, seed=SEED, **kwargs)


# -- reading stages back -----------------------------------------------------------------


def _plain(value):
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, Sdf.AssetPath):
        return value.resolvedPath
    try:
        return np.asarray(value, dtype=np.float64).tolist()
    except (TypeError, ValueError):
        return str(value)


def _snapshot(stage) -> dict:
    """Every prim (instance proxies and classes included): type, attribute values (default
    and time samples) and relationship targets."""
    out = {}
    predicate = Usd.TraverseInstanceProxies(Usd.PrimAllPrimsPredicate)
    for prim in Usd.PrimRange.Stage(stage, predicate):
        attributes = {}
        for attribute in prim.GetAttributes():
            samples = [(t, _plain(attribute.Get(t))) for t in attribute.GetTimeSamples()]
            attributes[attribute.GetName()] = (_plain(attribute.Get()), samples)
        relationships = {r.GetName(): [str(t) for t in r.GetTargets()] for r in prim.GetRelationships()}
        out[str(prim.GetPath())] = (prim.GetTypeName(), prim.IsActive(), attributes, relationships)
    return out


def _ao(stage, path):
    return np.asarray(stage.GetPrimAtPath(path).GetAttribute("primvars:ao").Get(), dtype=np.float64)


def _validation_errors(stage) -> list[str]:
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    errors = UsdValidation.ValidationContext(validators).Validate(stage)
    return sorted(f"{e.GetName()}: {e.GetMessage()}" for e in errors)


BAKED = ("/World/props/box", "/World/floor/box")


# -- the overlay -------------------------------------------------------------------------


def test_overlay_is_source_plus_ao_at_each_prim_path(tmp_path):
    source, positions, faces = _scene(tmp_path)
    source_bytes = source.read_bytes()
    out = tmp_path / "scene_ao.usda"
    _bake(source, out, color=True)
    assert source.read_bytes() == source_bytes  # the user's file is untouched

    layer = Sdf.Layer.OpenAsAnonymous(str(out))
    assert list(layer.subLayerPaths) == ["scene.usda"]
    specs = []
    layer.Traverse(Sdf.Path.absoluteRootPath, lambda p: specs.append(p))
    prims = [layer.GetPrimAtPath(p) for p in specs if p.IsPrimPath()]
    assert prims and all(p.specifier == Sdf.SpecifierOver for p in prims)  # nothing defined
    authored = {str(p) for p in specs if p.IsPropertyPath()}
    assert authored == {f"{m}.primvars:{n}" for m in BAKED for n in ("ao", "displayColor")}
    data = layer.customLayerData["aobake"]
    assert data["source"] == "scene.usda" and data["time"] == "default"
    assert data["method"] == "embree" and data["n_rays"] == RAYS and data["seed"] == SEED

    before = _snapshot(Usd.Stage.Open(str(source)))
    stage = Usd.Stage.Open(str(out))
    after = _snapshot(stage)
    assert after.keys() == before.keys()  # same prim paths, duplicate names kept
    for path, (kind, active, attributes, relationships) in after.items():
        new = ("primvars:ao", "primvars:displayColor")
        popped = {k: attributes.pop(k) for k in new if k in attributes}
        added = {k: v for k, v in popped.items() if v != (None, [])}
        unset = {k: before[path][2].pop(k) for k in new if k in before[path][2]}
        assert all(value == (None, []) for value in unset.values()), path  # not in the source
        assert (kind, active, attributes, relationships) == before[path], path
        assert sorted(added) == (sorted(new) if path in BAKED else []), path
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(0.01)
    assert stage.GetTimeCodesPerSecond() == 30
    assert stage.GetDefaultPrim().GetPath() == Sdf.Path("/World")

    expected = _plain_bake(positions, faces)
    assert expected.min() < 0.9  # the box shadows the floor: a test that can fail
    got = np.concatenate([_ao(stage, p) for p in BAKED])
    np.testing.assert_array_equal(got, expected.astype(np.float32))
    for path in BAKED:
        primvar = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(path)).GetPrimvar("displayColor")
        assert primvar.GetInterpolation() == UsdGeom.Tokens.vertex
        colours = np.asarray(primvar.Get())
        np.testing.assert_array_equal(colours, np.repeat(_ao(stage, path)[:, None], 3, axis=1))
    # aobake's own readers see the source geometry and the ao
    np.testing.assert_allclose(load_mesh(out).positions, positions, atol=1e-6)
    np.testing.assert_array_equal(read_bake(out), got)


def test_overlay_and_outputs_validate_clean(tmp_path):
    source, _, _ = _scene(tmp_path)
    assert _validation_errors(Usd.Stage.Open(str(source))) == []
    outputs = [tmp_path / "o.usda", tmp_path / "p.usdz"]
    _bake(source, *outputs)
    copy = tmp_path / "c.usdc"
    _bake(source, copy, overlay=False)
    for path in [*outputs, copy]:
        assert _validation_errors(Usd.Stage.Open(str(path))) == [], path.name


def test_relative_sublayer_survives_moving_both_files(tmp_path):
    (tmp_path / "a" / "assets").mkdir(parents=True)
    (tmp_path / "a" / "baked").mkdir()
    source, _, _ = _scene(tmp_path / "a" / "assets")
    out = tmp_path / "a" / "baked" / "scene_ao.usdc"
    _bake(source, out)
    ao = read_bake(out)
    assert list(Sdf.Layer.OpenAsAnonymous(str(out)).subLayerPaths) == ["../assets/scene.usda"]
    shutil.move(tmp_path / "a", tmp_path / "b")
    moved = Usd.Stage.Open(str(tmp_path / "b" / "baked" / "scene_ao.usdc"))
    box = moved.GetPrimAtPath("/World/props/box")
    assert box.IsA(UsdGeom.Mesh) and len(box.GetAttribute("points").Get()) == 8
    np.testing.assert_array_equal(np.concatenate([_ao(moved, p) for p in BAKED]), ao)


def test_full_copy_keeps_hierarchy_primvars_and_materials(tmp_path):
    source, positions, faces = _scene(tmp_path)
    overlay, copy = tmp_path / "o.usda", tmp_path / "c.usda"
    _bake(source, overlay)
    _bake(source, copy, overlay=False)
    layer = Sdf.Layer.OpenAsAnonymous(str(copy))
    assert list(layer.subLayerPaths) == []  # self-contained
    assert layer.customLayerData["aobake"]["source"] == "scene.usda"
    assert layer.GetPrimAtPath("/World/props/box").specifier == Sdf.SpecifierDef
    # the same composed scene as the overlay, prim for prim (texture path resolved alike)
    assert _snapshot(Usd.Stage.Open(str(copy))) == _snapshot(Usd.Stage.Open(str(overlay)))
    stage = Usd.Stage.Open(str(copy))
    ops = UsdGeom.Xformable(stage.GetPrimAtPath("/World/props")).GetXformOpOrderAttr().Get()
    assert list(ops) == ["xformOp:translate", "xformOp:scale"]
    box = stage.GetPrimAtPath("/World/props/box")
    assert UsdGeom.PrimvarsAPI(box).GetPrimvar("st").GetInterpolation() == UsdGeom.Tokens.faceVarying
    bound, _ = UsdShade.MaterialBindingAPI(box).ComputeBoundMaterial()
    assert bound.GetPath() == Sdf.Path("/World/Looks/Mat")
    np.testing.assert_array_equal(read_bake(copy), _plain_bake(positions, faces).astype(np.float32))


def test_usdz_is_self_contained_with_ao_and_textures(tmp_path):
    source, positions, faces = _scene(tmp_path / "src")
    out = tmp_path / "scene.usdz"
    _bake(source, out)
    shutil.rmtree(tmp_path / "src")  # nothing outside the package is needed
    names = zipfile.ZipFile(out).namelist()
    assert names[0] == "scene.usdc" and any(n.endswith("grid.png") for n in names)
    stage = Usd.Stage.Open(str(out))
    got = np.concatenate([_ao(stage, p) for p in BAKED])
    np.testing.assert_array_equal(got, _plain_bake(positions, faces).astype(np.float32))
    texture = stage.GetPrimAtPath("/World/Looks/Mat/Tex").GetAttribute("inputs:file").Get()
    assert texture.resolvedPath and "scene.usdz" in texture.resolvedPath
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z


def test_usdz_from_a_non_usd_input(tmp_path):
    from aobake.io import write_ply

    points, quads = _grid(cells=3)
    ply = tmp_path / "plate.ply"
    write_ply(ply, points, _triangles(quads), np.ones(len(points)))
    _bake(ply, tmp_path / "plate.usdz")
    stage = Usd.Stage.Open(str(tmp_path / "plate.usdz"))
    np.testing.assert_array_equal(_ao(stage, "/Root/plate"), np.ones(len(points), dtype=np.float32))
    assert stage.GetRootLayer().customLayerData["aobake"]["source"] == "plate.ply"


# -- instancing, indexed primvars, time samples ---------------------------------------------


def test_instances_get_their_own_ao(tmp_path):
    path = tmp_path / "inst.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    proto = stage.CreateClassPrim("/Proto")
    box_points, box_quads = _cube((-0.25, -0.25, 0.0), (0.25, 0.25, 0.5))
    _mesh(stage, "/Proto/box", box_points, box_quads)
    floor_points, floor_quads = _grid()
    _mesh(stage, "/World/floor", floor_points, floor_quads)
    offsets = {"/World/low": (0.0, 0.0, 0.0), "/World/high": (1.0, 1.0, 3.0)}
    for where, offset in offsets.items():
        xform = UsdGeom.Xform.Define(stage, where)
        xform.AddTranslateOp().Set(Gf.Vec3d(*offset))
        xform.GetPrim().GetReferences().AddInternalReference(proto.GetPath())
        xform.GetPrim().SetInstanceable(True)
    stage.GetRootLayer().Save()
    del stage
    source_bytes = path.read_bytes()

    out = tmp_path / "inst_ao.usda"
    _bake(path, out)
    assert path.read_bytes() == source_bytes
    composed = Usd.Stage.Open(str(out))
    assert not composed.GetPrimAtPath("/World/low").IsInstance()  # de-instanced in the overlay
    assert Usd.Stage.Open(str(path)).GetPrimAtPath("/World/low").IsInstance()
    order = ["/World/floor", "/World/low/box", "/World/high/box"]
    positions = np.vstack([floor_points, box_points + offsets["/World/low"], box_points + offsets["/World/high"]])
    n = len(floor_points)
    faces = np.vstack([_triangles(floor_quads), _triangles(box_quads) + n, _triangles(box_quads) + n + 8])
    expected = _plain_bake(positions, faces).astype(np.float32)
    got = [_ao(composed, p) for p in order]
    np.testing.assert_array_equal(np.concatenate(got), expected)
    assert not np.array_equal(got[1], got[2])  # the resting box is darker at its foot
    copy = tmp_path / "inst_copy.usdc"
    _bake(path, copy, overlay=False)
    flat = Usd.Stage.Open(str(copy))
    np.testing.assert_array_equal(np.concatenate([_ao(flat, p) for p in order]), expected)


def test_indexed_display_color_of_the_source_is_replaced(tmp_path):
    source, _, _ = _scene(tmp_path)
    stage = Usd.Stage.Open(str(source))
    primvar = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/props/box")).CreatePrimvar(
        "displayColor", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.uniform
    )
    primvar.Set(Vt.Vec3fArray([(1, 0, 0)]))
    primvar.SetIndices(Vt.IntArray([0] * 6))
    stage.GetRootLayer().Save()
    del stage
    out = tmp_path / "o.usda"
    _bake(source, out, color=True)
    composed = Usd.Stage.Open(str(out))
    primvar = UsdGeom.PrimvarsAPI(composed.GetPrimAtPath("/World/props/box")).GetPrimvar("displayColor")
    assert not primvar.IsIndexed() and primvar.GetInterpolation() == UsdGeom.Tokens.vertex
    flat = np.asarray(primvar.ComputeFlattened())
    np.testing.assert_array_equal(flat[:, 0], _ao(composed, "/World/props/box"))


def _animated_scene(path: Path):
    """A floor and a box whose points are time-sampled only: high above at t=1, resting
    at t=10. Returns the file and the two world-space point sets of the box."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    stage.SetTimeCodesPerSecond(30)
    floor_points, floor_quads = _grid()
    _mesh(stage, "/World/floor", floor_points, floor_quads)
    box_points, box_quads = _cube((-0.5, -0.5, 0.0), (0.5, 0.5, 1.0))
    mesh = _mesh(stage, "/World/box", box_points, box_quads)
    points = mesh.GetPointsAttr()
    points.Clear()
    high = box_points + (0.0, 0.0, 5.0)
    points.Set(Vt.Vec3fArray.FromNumpy(high.astype(np.float32)), 1.0)
    points.Set(Vt.Vec3fArray.FromNumpy(box_points.astype(np.float32)), 10.0)
    stage.GetRootLayer().Save()
    del stage
    faces = np.vstack([_triangles(floor_quads), _triangles(box_quads) + len(floor_points)])
    return floor_points, {1.0: high, 10.0: box_points}, faces


def test_time_samples_baked_at_time(tmp_path):
    source = tmp_path / "anim.usda"
    floor, box, faces = _animated_scene(source)
    out = tmp_path / "anim_ao.usda"
    report = _bake(source, out, time=10)
    assert "1 animated mesh read at time 10" in report.summary()
    expected = _plain_bake(np.vstack([floor, box[10.0]]), faces).astype(np.float32)
    composed = Usd.Stage.Open(str(out))
    np.testing.assert_array_equal(np.concatenate([_ao(composed, "/World/floor"), _ao(composed, "/World/box")]), expected)
    assert Sdf.Layer.OpenAsAnonymous(str(out)).customLayerData["aobake"]["time"] == 10.0
    # the animation itself is the source's, at the source's time scale (30 per second:
    # under a root layer at the default 24 the samples would move to 0.8 and 8)
    points = composed.GetPrimAtPath("/World/box").GetAttribute("points")
    for t in (1.0, 10.0):
        np.testing.assert_allclose(np.asarray(points.Get(t)), box[t])


def test_time_samples_without_time_read_at_the_earliest_sample(tmp_path):
    source = tmp_path / "anim.usda"
    floor, box, faces = _animated_scene(source)
    report = _bake(source, tmp_path / "a.usda")
    assert "1 animated mesh read at time 1" in report.summary()
    expected = _plain_bake(np.vstack([floor, box[1.0]]), faces).astype(np.float32)
    np.testing.assert_array_equal(read_bake(tmp_path / "a.usda"), expected)
    resting = _plain_bake(np.vstack([floor, box[10.0]]), faces)
    assert expected[: len(floor)].min() > resting[: len(floor)].min() + 0.1  # a different instant
    # a static scene says nothing about time
    static, _, _ = _scene(tmp_path)
    assert "animated" not in _bake(static, tmp_path / "s.usda").summary()


# -- errors ------------------------------------------------------------------------------


def _one_line_error(runner, args, directory, expected):
    before = sorted(p.name for p in directory.rglob("*"))
    result = runner.invoke(main, ["bake", *args, "--rays", "4", "-q"])
    assert result.exit_code == 1, result.output
    assert result.stderr == f"Error: {expected}\n", result.stderr
    assert sorted(p.name for p in directory.rglob("*")) == before  # no partial output


def test_overlay_refusals_are_one_line_errors(runner, tmp_path):
    source, _, _ = _scene(tmp_path)
    points, quads = _grid(cells=2)
    from aobake.io import write_ply

    ply = tmp_path / "plate.ply"
    write_ply(ply, points, _triangles(quads), np.ones(len(points)))
    _one_line_error(
        runner, [str(ply), "-o", str(tmp_path / "p.usda"), "--overlay"], tmp_path,
        "p.usda: an overlay needs a USD input to layer over",
    )
    _one_line_error(
        runner, [str(source), "-o", str(tmp_path / "p.usdz"), "--overlay"], tmp_path,
        "p.usdz: a .usdz package is self-contained and cannot be an overlay; "
        "write the overlay as .usda, .usdc or .usd",
    )
    _one_line_error(
        runner, [str(source), "-o", str(source)], tmp_path,
        "scene.usda: is also an input; refusing to write over it",
    )
    _one_line_error(
        runner, [str(ply), "-o", str(tmp_path / "p.ply"), "--time", "3"], tmp_path,
        "plate.ply: a time was given but PLY files have no time samples (USD only)",
    )


def test_cli_overlay_by_default_and_full_copy_on_request(runner, tmp_path):
    source, _, _ = _scene(tmp_path)
    result = runner.invoke(main, ["bake", str(source), "-o", str(tmp_path / "o.usda"), "--rays", "4", "-q"])
    assert result.exit_code == 0, result.output
    assert list(Sdf.Layer.OpenAsAnonymous(str(tmp_path / "o.usda")).subLayerPaths) == ["scene.usda"]
    result = runner.invoke(
        main, ["bake", str(source), "-o", str(tmp_path / "c.usda"), "--rays", "4", "-q", "--no-overlay"]
    )
    assert result.exit_code == 0, result.output
    assert list(Sdf.Layer.OpenAsAnonymous(str(tmp_path / "c.usda")).subLayerPaths) == []
    np.testing.assert_array_equal(read_bake(tmp_path / "o.usda"), read_bake(tmp_path / "c.usda"))


def test_same_inputs_give_identical_files(tmp_path):
    source, _, _ = _scene(tmp_path)
    for name in ("a", "b"):
        _bake(source, tmp_path / f"{name}.usda", tmp_path / f"{name}.usdz", color=True)
        _bake(source, tmp_path / f"{name}_copy.usdc", overlay=False)
    for suffix in (".usda", ".usdz", "_copy.usdc"):
        assert (tmp_path / f"a{suffix}").read_bytes() == (tmp_path / f"b{suffix}").read_bytes(), suffix
    # every entry carries a fixed time, not the clock of the bake; the package stays valid
    archive = zipfile.ZipFile(tmp_path / "a.usdz")
    assert {info.date_time for info in archive.infolist()} == {(2000, 1, 1, 0, 0, 0)}
    assert archive.testzip() is None


def test_list_of_names_in_custom_data(tmp_path):
    # the pipeline records --field files as a list: it was refused with a traceback
    from aobake.io import write_bake

    source, _, _ = _scene(tmp_path)
    surface = load_mesh(source)
    ao = np.ones(surface.n_vertices)
    data = {"method": "embree", "fields": ["rock.npz", "tree.npz"]}
    write_bake(tmp_path / "own.usda", surface_from_arrays(surface.positions, surface.faces), ao, custom_data=data)
    write_bake(tmp_path / "over.usda", surface, ao, custom_data=data)
    stage = Usd.Stage.Open(str(tmp_path / "own.usda"))
    own = stage.GetPrimAtPath("/Root").GetCustomDataByKey("aobake")
    assert list(own["fields"]) == ["rock.npz", "tree.npz"]
    layer = Sdf.Layer.OpenAsAnonymous(str(tmp_path / "over.usda"))
    assert list(layer.customLayerData["aobake"]["fields"]) == ["rock.npz", "tree.npz"]


# -- --channel: ao into the source's own colours -----------------------------------------


def _coloured_scene(tmp_path, floor_interpolation):
    """The scene with seeded random colours: uniform on the box, ``floor_interpolation``
    on the floor. Returns the file and, per baked mesh, its colours as authored."""
    source, _, _ = _scene(tmp_path)
    rng = np.random.default_rng(7)
    stage = Usd.Stage.Open(str(source))
    authored = {}
    for path, interpolation in zip(BAKED, ("uniform", floor_interpolation), strict=True):
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath(path))
        n = {
            "constant": 1,
            "uniform": len(mesh.GetFaceVertexCountsAttr().Get()),
            "vertex": len(mesh.GetPointsAttr().Get()),
            "faceVarying": len(mesh.GetFaceVertexIndicesAttr().Get()),
        }[interpolation]
        colours = rng.random((n, 3)).astype(np.float32)
        mesh.CreateDisplayColorPrimvar(interpolation).Set(Vt.Vec3fArray.FromNumpy(colours))
        authored[path] = (interpolation, colours)
    stage.GetRootLayer().Save()
    del stage
    return source, authored


@pytest.mark.parametrize("floor_interpolation", ["constant", "vertex", "faceVarying"])
def test_channel_writes_ao_into_one_colour_component(tmp_path, floor_interpolation):
    source, authored = _coloured_scene(tmp_path, floor_interpolation)
    out = tmp_path / "o.usda"
    _bake(source, out, channel="G")
    stage = Usd.Stage.Open(str(out))
    for path, (interpolation, colours) in authored.items():
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath(path))
        counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
        indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get())
        ao = _ao(stage, path)
        primvar = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("displayColor")
        got = np.asarray(primvar.ComputeFlattened())
        # per-face colours survive as faceVarying; others become one colour per vertex
        if interpolation in ("uniform", "faceVarying"):
            assert primvar.GetInterpolation() == "faceVarying"
            kept = np.repeat(colours, counts, axis=0) if interpolation == "uniform" else colours
            np.testing.assert_array_equal(got[:, 1], ao[indices])
        else:
            assert primvar.GetInterpolation() == "vertex"
            kept = np.repeat(colours, len(ao), axis=0) if interpolation == "constant" else colours
            np.testing.assert_array_equal(got[:, 1], ao)
        np.testing.assert_array_equal(got[:, [0, 2]], kept[:, [0, 2]])  # bit-identical
    assert ao.min() < 0.9


def test_channel_a_writes_display_opacity(tmp_path):
    source, authored = _coloured_scene(tmp_path, "vertex")
    out = tmp_path / "o.usdz"
    _bake(source, out, channel="A")
    stage = Usd.Stage.Open(str(out))
    for path, (_, colours) in authored.items():
        api = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(path))
        opacity = api.GetPrimvar("displayOpacity")
        assert opacity.GetInterpolation() == "vertex"
        np.testing.assert_array_equal(np.asarray(opacity.Get()), _ao(stage, path))
        np.testing.assert_array_equal(np.asarray(api.GetPrimvar("displayColor").Get()), colours)


def test_channel_without_colours_is_refused_before_baking(runner, tmp_path):
    source, _, _ = _scene(tmp_path)
    _one_line_error(
        runner, [str(source), "-o", str(tmp_path / "o.usda"), "--channel", "R"], tmp_path,
        "scene.usda: --channel R: /World/props/box has no primvars:displayColor to write into",
    )
