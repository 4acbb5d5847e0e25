"""USD writer and reader: read back through the UsdGeom schema API (OpenUSD's own tests)."""

from __future__ import annotations

import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Sdf, Usd, UsdGeom  # noqa: E402

from aobake.errors import InputError, NumericalError, OutputError  # noqa: E402
from aobake.io import read_bake, usd, write_bake  # noqa: E402
from aobake.io.usd import read_ao_usd, write_usd  # noqa: E402
from aobake.mesh import Part, Surface, surface_from_arrays  # noqa: E402

SUFFIXES = [".usda", ".usdc", ".usd"]


def _single():
    positions = np.array(
        [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 1.0, 0.5], [0.0, 1.0, -0.5], [9.0, 9.0, 9.0]]
    )
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    surface = surface_from_arrays(positions, faces, name="my mesh")
    ao = np.array([0.0, 0.25, 0.5, 0.875, 1.0])
    return surface, ao


def _two_parts(name_a="quad-part", name_b="tri"):
    """Part A: one quad (kept as a quad in USD); part B: one triangle, offset in space."""
    positions = np.array(
        [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
            [3.0, 0.0, 1.0],
            [4.0, 0.0, 1.0],
            [3.0, 2.0, 1.0],
        ]
    )
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]])
    normals = np.tile([0.0, 0.0, 1.0], (7, 1))
    quad = Part(name_a, 0, 4, 0, 2, np.array([4]), np.array([0, 1, 2, 3]))
    tri = Part(name_b, 4, 7, 2, 3, np.array([3]), np.array([0, 1, 2]))
    surface = Surface(positions, faces, normals, (quad, tri), "two.usda")
    ao = np.linspace(0.0, 1.0, 7)
    return surface, ao


def _meshes(stage):
    return [UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_schema_read_back(tmp_path, suffix):
    surface, ao = _single()
    out = tmp_path / f"bake{suffix}"
    custom = {"method": "embree", "rays": 256, "seed": 0, "max_distance": 1.5, "adaptive": False}
    write_usd(out, surface, ao, color=True, up_axis="Z", meters_per_unit=0.01, custom_data=custom)
    stage = Usd.Stage.Open(str(out))
    # The ".usd" format writes crate by default; the magic bytes say which one we got.
    assert out.read_bytes()[:8] == (b"#usda 1." if suffix == ".usda" else b"PXR-USDC")

    assert stage.HasAuthoredMetadata("metersPerUnit") and stage.HasAuthoredMetadata("upAxis")
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(0.01)
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    root = stage.GetDefaultPrim()
    assert root.GetPath() == Sdf.Path("/Root") and root.IsA(UsdGeom.Xform)
    assert dict(root.GetCustomDataByKey("aobake")) == custom

    (mesh,) = _meshes(stage)
    assert mesh.GetPath() == Sdf.Path("/Root/my_mesh")
    assert dict(mesh.GetPrim().GetCustomDataByKey("aobake")) == custom
    primvar = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("ao")
    assert primvar.GetDeclarationInfo() == (
        "ao",
        Sdf.ValueTypeNames.FloatArray,
        UsdGeom.Tokens.vertex,
        1,
    )
    values = np.asarray(primvar.Get())
    assert values.dtype == np.float32
    np.testing.assert_array_equal(values, ao.astype(np.float32))

    points = np.asarray(mesh.GetPointsAttr().Get())
    assert points.shape == (5, 3)
    np.testing.assert_array_equal(points, surface.positions.astype(np.float32))
    counts = mesh.GetFaceVertexCountsAttr().Get()
    indices = mesh.GetFaceVertexIndicesAttr().Get()
    valid, reason = UsdGeom.Mesh.ValidateTopology(indices, counts, len(points))
    assert valid, reason
    np.testing.assert_array_equal(np.asarray(indices), surface.faces.reshape(-1))
    assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none

    normals = np.asarray(mesh.GetNormalsAttr().Get())
    assert mesh.GetNormalsInterpolation() == UsdGeom.Tokens.vertex
    np.testing.assert_allclose(normals, surface.normals, atol=1e-7)

    extent = np.asarray(mesh.GetExtentAttr().Get())
    np.testing.assert_array_equal(extent, [points.min(axis=0), points.max(axis=0)])
    np.testing.assert_array_equal(extent, [[0.0, 0.0, -0.5], [9.0, 9.0, 9.0]])

    display = mesh.GetDisplayColorPrimvar()
    assert display.GetInterpolation() == UsdGeom.Tokens.vertex
    np.testing.assert_array_equal(
        np.asarray(display.Get()), np.repeat(ao.astype(np.float32)[:, None], 3, axis=1)
    )

    np.testing.assert_array_equal(read_ao_usd(out), ao.astype(np.float32))


def test_defaults_author_y_up_and_meters(tmp_path):
    surface, ao = _single()
    out = tmp_path / "bake.usda"
    write_usd(out, surface, ao)
    stage = Usd.Stage.Open(str(out))
    assert stage.HasAuthoredMetadata("metersPerUnit") and stage.HasAuthoredMetadata("upAxis")
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    (mesh,) = _meshes(stage)
    assert not mesh.GetDisplayColorPrimvar().HasAuthoredValue()
    assert not stage.GetDefaultPrim().HasCustomDataKey("aobake")


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_multi_part_keeps_original_polygons(tmp_path, suffix):
    surface, ao = _two_parts()
    out = tmp_path / f"parts{suffix}"
    write_usd(out, surface, ao, custom_data={"method": "bunnell"})
    stage = Usd.Stage.Open(str(out))
    meshes = _meshes(stage)
    assert [m.GetPath().name for m in meshes] == ["quad_part", "tri"]
    expected = [(4, [4], [0, 1, 2, 3]), (3, [3], [0, 1, 2])]
    for mesh, (n_points, counts, indices), start in zip(meshes, expected, [0, 4], strict=True):
        points = mesh.GetPointsAttr().Get()
        assert len(points) == n_points
        assert list(mesh.GetFaceVertexCountsAttr().Get()) == counts
        assert list(mesh.GetFaceVertexIndicesAttr().Get()) == indices
        assert UsdGeom.Mesh.ValidateTopology(
            mesh.GetFaceVertexIndicesAttr().Get(), mesh.GetFaceVertexCountsAttr().Get(), n_points
        )[0]
        np.testing.assert_array_equal(
            np.asarray(points), surface.positions[start : start + n_points].astype(np.float32)
        )
        primvar = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("ao")
        assert len(primvar.Get()) == n_points
        assert mesh.GetPrim().GetCustomDataByKey("aobake") == {"method": "bunnell"}
    extent = np.asarray(meshes[1].GetExtentAttr().Get())
    np.testing.assert_array_equal(extent, [[3.0, 0.0, 1.0], [4.0, 2.0, 1.0]])
    np.testing.assert_array_equal(read_ao_usd(out), ao.astype(np.float32))


def test_part_names_made_valid_and_unique(tmp_path):
    surface, ao = _two_parts("1 body", "1 body")
    out = tmp_path / "names.usda"
    write_usd(out, surface, ao)
    names = [m.GetPath().name for m in _meshes(Usd.Stage.Open(str(out)))]
    assert len(set(names)) == 2
    assert all(Sdf.Path.IsValidIdentifier(n) for n in names)
    assert names[1] == names[0] + "_1"


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_same_path_twice_in_one_process(tmp_path, suffix):
    surface, ao = _single()
    out = tmp_path / f"again{suffix}"
    write_usd(out, surface, ao)
    np.testing.assert_array_equal(read_ao_usd(out), ao.astype(np.float32))
    held = Usd.Stage.Open(str(out))  # a caller keeps the old layer registered
    second = 1.0 - ao
    write_usd(out, surface, second)
    np.testing.assert_array_equal(read_ao_usd(out), second.astype(np.float32))
    third = np.full_like(ao, 0.5)
    write_usd(out, surface, third)
    np.testing.assert_array_equal(read_ao_usd(out), third.astype(np.float32))
    del held
    np.testing.assert_array_equal(read_ao_usd(out), third.astype(np.float32))
    assert sorted(p.name for p in tmp_path.iterdir()) == [out.name]
    assert not _registered_temp_layers(tmp_path, out)


def _registered_temp_layers(directory, out):
    """Layers still in USD's registry for files in ``directory`` other than ``out``."""
    prefix = str(directory.resolve())
    return [
        layer.identifier
        for layer in Sdf.Layer.GetLoadedLayers()
        if layer.identifier.startswith(prefix) and layer.identifier != str(out.resolve())
    ]


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_same_input_gives_identical_bytes(tmp_path, suffix):
    surface, ao = _two_parts()
    write_usd(tmp_path / f"a{suffix}", surface, ao, custom_data={"seed": 1})
    write_usd(tmp_path / f"b{suffix}", surface, ao, custom_data={"seed": 1})
    assert (tmp_path / f"a{suffix}").read_bytes() == (tmp_path / f"b{suffix}").read_bytes()


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_failure_midway_leaves_nothing(tmp_path, monkeypatch, suffix):
    surface, ao = _two_parts()
    real = usd._author_mesh
    calls = []

    def second_mesh_fails(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("interrupted")
        return real(*args, **kwargs)

    monkeypatch.setattr(usd, "_author_mesh", second_mesh_fails)
    out = tmp_path / f"fail{suffix}"
    with pytest.raises(RuntimeError, match="interrupted") as info:
        write_usd(out, surface, ao)
    assert len(calls) == 2
    assert list(tmp_path.iterdir()) == []
    # Even while the traceback (and the writer's frames) are alive, the stage is gone.
    assert info.value.__traceback__ is not None
    assert not _registered_temp_layers(tmp_path, out)


def test_failure_keeps_previous_output(tmp_path, monkeypatch):
    surface, ao = _single()
    out = tmp_path / "keep.usdc"
    write_usd(out, surface, ao)
    before = out.read_bytes()
    monkeypatch.setattr(
        usd, "_author_mesh", lambda *a, **k: (_ for _ in ()).throw(OSError(28, "No space left"))
    )
    with pytest.raises(OutputError, match="No space left"):
        write_usd(out, surface, np.zeros(5))
    assert out.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["keep.usdc"]


@pytest.mark.parametrize("bad", [np.nan, -0.5, 2.0])
def test_bad_ao_raises_before_anything_is_created(tmp_path, bad):
    surface, good = _single()
    ao = good.copy()
    ao[1] = bad
    with pytest.raises(NumericalError):
        write_usd(tmp_path / "bad.usda", surface, ao)
    with pytest.raises(NumericalError, match="5 vertices"):
        write_usd(tmp_path / "bad.usda", surface, good[:4])
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"up_axis": "X"}, "up_axis"),
        ({"meters_per_unit": 0.0}, "meters_per_unit"),
        ({"meters_per_unit": float("nan")}, "meters_per_unit"),
        ({"custom_data": {"rays": [1, 2]}}, "custom_data"),
        ({"custom_data": {3: "x"}}, "custom_data"),
    ],
)
def test_bad_options_raise_before_anything_is_created(tmp_path, kwargs, message):
    surface, ao = _single()
    with pytest.raises(ValueError, match=message):
        write_usd(tmp_path / "bad.usda", surface, ao, **kwargs)
    assert list(tmp_path.iterdir()) == []


def test_bad_topology_is_input_error(tmp_path):
    surface, ao = _two_parts()
    quad, tri = surface.parts
    broken = Part(tri.name, 4, 7, 2, 3, np.array([3]), np.array([0, 1, 3]))
    bad = Surface(surface.positions, surface.faces, surface.normals, (quad, broken), "two.usda")
    with pytest.raises(InputError, match="two.usda: part 'tri'"):
        write_usd(tmp_path / "bad.usda", bad, ao)
    assert list(tmp_path.iterdir()) == []


def test_missing_directory_is_output_error(tmp_path):
    surface, ao = _single()
    with pytest.raises(OutputError, match="does not exist"):
        write_usd(tmp_path / "nope" / "bake.usda", surface, ao)


def test_read_errors(tmp_path):
    with pytest.raises(InputError, match="missing.usda: file not found"):
        read_ao_usd(tmp_path / "missing.usda")
    garbage = tmp_path / "garbage.usdc"
    garbage.write_bytes(b"\x00not a crate file" * 20)
    with pytest.raises(InputError, match="garbage.usdc: not a readable USD file"):
        read_ao_usd(garbage)
    text = tmp_path / "garbage.usda"
    text.write_text("#usda 1.0\ndef Mesh {{{\n")
    with pytest.raises(InputError, match="garbage.usda: not a readable USD file"):
        read_ao_usd(text)

    plain = tmp_path / "plain.usda"
    stage = Usd.Stage.CreateNew(str(plain))
    mesh = UsdGeom.Mesh.Define(stage, "/World/m")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    stage.Save()
    del stage, mesh
    with pytest.raises(InputError, match="no mesh with a primvar 'ao'"):
        read_ao_usd(plain)


def test_read_rejects_partial_or_misshapen_ao(tmp_path):
    surface, ao = _two_parts()
    out = tmp_path / "parts.usda"
    write_usd(out, surface, ao)
    stage = Usd.Stage.Open(str(out))
    UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Root/tri")).RemovePrimvar("ao")
    stage.GetRootLayer().Export(str(tmp_path / "partial.usda"))
    UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Root/quad_part")).GetPrimvar("ao").Set([0.5, 0.5])
    stage.GetRootLayer().Export(str(tmp_path / "short.usda"))
    del stage
    with pytest.raises(InputError, match="1 meshes have no primvar 'ao' \\(first: /Root/tri\\)"):
        read_ao_usd(tmp_path / "partial.usda")
    with pytest.raises(InputError, match="2 vertex values but the mesh has 4 points"):
        read_ao_usd(tmp_path / "short.usda")


def test_indexed_primvar_from_other_tools_is_flattened(tmp_path):
    path = tmp_path / "indexed.usda"
    stage = Usd.Stage.CreateNew(str(path))
    mesh = UsdGeom.Mesh.Define(stage, "/m")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
        "ao", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex
    )
    primvar.Set([0.25, 1.0])
    primvar.SetIndices([1, 0, 1])
    stage.Save()
    del stage, mesh, primvar
    np.testing.assert_array_equal(read_ao_usd(path), [1.0, 0.25, 1.0])


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_write_bake_and_read_bake_usd(tmp_path, suffix):
    surface, ao = _two_parts()
    out = tmp_path / f"bake{suffix}"
    write_bake(
        out,
        surface,
        ao,
        color=True,
        up_axis="Z",
        meters_per_unit=0.001,
        custom_data={"method": "field"},
    )
    stage = Usd.Stage.Open(str(out))
    assert len(_meshes(stage)) == 2
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(0.001)
    del stage
    np.testing.assert_array_equal(read_bake(out, n_vertices=7), ao.astype(np.float32))
    with pytest.raises(NumericalError, match="7 vertices"):
        write_bake(tmp_path / f"short{suffix}", surface, ao[:5])
