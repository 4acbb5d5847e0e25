"""Extra per-vertex attributes (``attributes=``) and display colours (``display=``) in
every writer path: PLY plain and kept, USD new, overlay, flattened copy and .usdz, glTF
new and kept. Read back with plyfile, pxr and a plain glTF decoder (tests/gltf_assets.py)."""

from __future__ import annotations

import zipfile

import gltf_assets as ga
import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from aobake.errors import NumericalError
from aobake.io import load_mesh, write_bake
from aobake.io.color import srgb_bytes
from aobake.testing import scenes

pxr = pytest.importorskip("pxr")
from pxr import Sdf, Usd, UsdGeom, Vt  # noqa: E402


def _values(n: int, seed: int = 0):
    """ao, attributes of the three kinds, and display colours for n vertices."""
    rng = np.random.default_rng(seed)
    bent = rng.normal(size=(n, 3))
    bent /= np.linalg.norm(bent, axis=1, keepdims=True)
    attributes = {
        "bentNormal": bent,
        "irradiance": 3.0 * rng.random((n, 3)),  # radiometric: may exceed 1
        "cavity": rng.random(n),
    }
    return rng.random(n), attributes, rng.random((n, 3))


# -- the inputs --------------------------------------------------------------------------


def _usd_source(path):
    """Two meshes under transforms, one with a primvar the overlay must not disturb."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(stage.GetPrimAtPath("/World"))
    for prim_path, (points, faces) in (
        ("/World/a/tet", (scenes.icosphere(0, 1.0, (0, 0, 0)))),
        ("/World/b/ball", (scenes.icosphere(1, 0.5, (3, 0, 0)))),
    ):
        mesh = UsdGeom.Mesh.Define(stage, prim_path)
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(faces)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([int(k) for k in faces.ravel()]))
    stage.GetRootLayer().Save()
    return path


def _ply_source(path):
    points, faces = scenes.icosphere(1, 1.0)
    v = np.zeros(len(points), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("u", "f4"), ("v", "f4")])
    v["x"], v["y"], v["z"] = points.T
    v["u"] = np.arange(len(points)) / len(points)
    f = np.zeros(len(faces), dtype=[("vertex_indices", "i4", (3,))])
    f["vertex_indices"] = faces
    PlyData([PlyElement.describe(v, "vertex"), PlyElement.describe(f, "face")]).write(str(path))
    return path


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    d = tmp_path_factory.mktemp("sources")
    arrays = scenes.combine_meshes(scenes.icosphere(0), scenes.icosphere(1, 0.5, (3, 0, 0)),
                                   names=["tet", "ball"])  # fmt: skip
    return {
        "arrays": arrays,
        "ply": load_mesh(_ply_source(d / "in.ply")),
        "usd": load_mesh(_usd_source(d / "in.usda")),
        "gltf": load_mesh(ga.write_scene(d / "in.glb")),
    }


# -- reading back ------------------------------------------------------------------------


def _read_ply(path):
    data = PlyData.read(str(path))["vertex"].data
    names = data.dtype.names
    out = {"ao": data["ao"]}
    for name, suffixes in (("bentNormal", "xyz"), ("irradiance", "rgb")):
        out[name] = np.column_stack([data[f"{name}_{c}"] for c in suffixes])
        assert all(data.dtype[f"{name}_{c}"] == np.float32 for c in suffixes)
    out["cavity"] = data["cavity"]
    assert data.dtype["cavity"] == np.float32
    if "red" in names:  # sRGB bytes
        out["color"] = np.column_stack([data[c] for c in ("red", "green", "blue")])
    return out, names


def _read_usd(path, prim_paths):
    stage = Usd.Stage.Open(str(path))
    out: dict = {}
    types = {}
    for prim_path in prim_paths:
        prim = stage.GetPrimAtPath(prim_path)
        api = UsdGeom.PrimvarsAPI(prim)
        for name in ("ao", "bentNormal", "irradiance", "cavity", "displayColor"):
            primvar = api.GetPrimvar(name)
            if not primvar or not primvar.HasAuthoredValue():
                continue
            assert primvar.GetInterpolation() == UsdGeom.Tokens.vertex, (prim_path, name)
            types[name] = str(primvar.GetTypeName())
            out.setdefault(name, []).append(np.asarray(primvar.ComputeFlattened(), dtype=np.float32))
    del stage
    return {k: np.concatenate(v) for k, v in out.items()}, types


def _read_gltf(path, surface, color):
    gl, blobs = ga.load(path)
    nodes = {n.get("name"): n for n in gl["nodes"] if "mesh" in n}
    out: dict = {}
    for part in surface.parts:
        attributes = gl["meshes"][nodes[part.name]["mesh"]]["primitives"][0]["attributes"]
        for key, name in (("_AO", "ao"), ("_BENTNORMAL", "bentNormal"), ("_IRRADIANCE", "irradiance"),
                          ("_CAVITY", "cavity"), ("COLOR_0", "color")):  # fmt: skip
            if key not in attributes or (key == "COLOR_0" and not color):
                continue  # a source's own COLOR_0 is kept without --color
            a = gl["accessors"][attributes[key]]
            assert a["componentType"] == 5126 and a["type"] == ("SCALAR" if name in ("ao", "cavity") else "VEC3")
            values = ga.accessor(gl, blobs, attributes[key])
            out.setdefault(name, []).append(values[:, 0] if a["type"] == "SCALAR" else values)
    return {k: np.concatenate(v) for k, v in out.items()}, gl


# -- every path --------------------------------------------------------------------------

#: (source, output name, write_bake options, reader)
PATHS = [
    ("arrays", "plain.ply", {}, "ply"),
    ("ply", "kept.ply", {}, "ply"),
    ("arrays", "new.usda", {}, "usd"),
    ("usd", "overlay.usda", {}, "usd"),
    ("usd", "copy.usdc", {"overlay": False}, "usd"),
    ("usd", "package.usdz", {}, "usd"),
    ("arrays", "package.usdz", {}, "usd"),
    ("arrays", "new.glb", {}, "gltf"),
    ("ply", "new.gltf", {}, "gltf"),
    ("gltf", "kept.glb", {}, "gltf"),
    ("gltf", "kept.gltf", {}, "gltf"),
]


def _usd_prims(source, surface, path):
    if source == "usd":
        return [part.prim_path for part in surface.parts]
    stage = Usd.Stage.Open(str(path))
    prims = [str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    del stage
    return prims


@pytest.mark.parametrize("color", [False, True])
@pytest.mark.parametrize(("source", "name", "options", "reader"), PATHS)
def test_attributes_reach_every_writer_path(tmp_path, sources, source, name, options, reader, color):
    surface = sources[source]
    ao, attributes, display = _values(surface.n_vertices)
    path = tmp_path / name
    write_bake(path, surface, ao, attributes=attributes, display=display, color=color, **options)
    expected = {"ao": ao, **attributes}
    if reader == "ply":
        got, names = _read_ply(path)
        if color:
            np.testing.assert_array_equal(got.pop("color"), np.column_stack([srgb_bytes(c) for c in display.T]))
        else:
            assert "red" not in names
        if source == "ply":  # the input's own properties kept, in front
            assert names[:5] == ("x", "y", "z", "u", "v")
    elif reader == "usd":
        got, types = _read_usd(path, _usd_prims(source, surface, path))
        assert types["bentNormal"] == "normal3f[]" and types["irradiance"] == "color3f[]"
        assert types["cavity"] == "float[]"
        if color:
            np.testing.assert_array_equal(got.pop("displayColor"), display.astype(np.float32))
        else:
            assert "displayColor" not in got
        if name.endswith(".usdz"):
            assert zipfile.is_zipfile(path)
    else:
        got, _ = _read_gltf(path, surface, color)
        if color:
            np.testing.assert_array_equal(got.pop("color"), display.astype(np.float32))
    assert set(got) == set(expected)
    for key, values in expected.items():
        np.testing.assert_array_equal(got[key], np.asarray(values, dtype=np.float32), err_msg=key)


def test_without_display_color_stays_grey_ao(tmp_path, sources):
    surface = sources["arrays"]
    ao, attributes, _ = _values(surface.n_vertices)
    write_bake(tmp_path / "a.usda", surface, ao, attributes=attributes, color=True)
    got, _ = _read_usd(tmp_path / "a.usda", _usd_prims("arrays", surface, tmp_path / "a.usda"))
    np.testing.assert_array_equal(got["displayColor"], np.repeat(ao[:, None], 3, axis=1).astype(np.float32))


def test_kept_ply_replaces_an_attribute_of_the_same_name_in_place(tmp_path, sources):
    surface = sources["ply"]
    ao, attributes, _ = _values(surface.n_vertices)
    write_bake(tmp_path / "once.ply", surface, ao, attributes=attributes)
    again = load_mesh(tmp_path / "once.ply")
    ao2, attributes2, _ = _values(surface.n_vertices, seed=1)
    write_bake(tmp_path / "twice.ply", again, ao2, attributes=attributes2)
    got, names = _read_ply(tmp_path / "twice.ply")
    assert names == PlyData.read(str(tmp_path / "once.ply"))["vertex"].data.dtype.names
    np.testing.assert_array_equal(got["bentNormal"], attributes2["bentNormal"].astype(np.float32))


def test_overlay_holds_only_the_new_primvars(tmp_path, sources):
    surface = sources["usd"]
    ao, attributes, _ = _values(surface.n_vertices)
    write_bake(tmp_path / "o.usda", surface, ao, attributes=attributes)
    layer = Sdf.Layer.FindOrOpen(str(tmp_path / "o.usda"))
    for part in surface.parts:
        spec = layer.GetPrimAtPath(part.prim_path)
        assert spec.specifier == Sdf.SpecifierOver
        assert sorted(spec.attributes.keys()) == [
            "primvars:ao", "primvars:bentNormal", "primvars:cavity", "primvars:irradiance",
        ]  # fmt: skip
    from test_io_usd_overlay import _validation_errors

    assert _validation_errors(Usd.Stage.Open(str(tmp_path / "o.usda"))) == []


BAD = [
    ({"bentNormal": "short"}, "has shape"),
    ({"cavity": "vector"}, "has shape"),
    ({"irradiance": "nan"}, "non-finite"),
    ({"irradiance": "negative"}, "negative colour"),
    ({"ao": "scalar"}, "already written"),
    ({"bad name": "scalar"}, "not an identifier"),
]


@pytest.mark.parametrize(("attributes", "message"), BAD)
@pytest.mark.parametrize("name", ["out.ply", "out.usda", "out.glb", "out.usdz"])
def test_bad_attributes_write_nothing(tmp_path, sources, attributes, message, name):
    surface = sources["arrays"]
    n = surface.n_vertices
    make = {
        "short": np.zeros((n - 1, 3)),
        "vector": np.zeros((n, 3)),
        "nan": np.full((n, 3), np.nan),
        "negative": -np.ones((n, 3)),
        "scalar": np.zeros(n),
    }
    values = {key: make[kind] for key, kind in attributes.items()}
    with pytest.raises(NumericalError, match=message):
        write_bake(tmp_path / name, surface, np.ones(n), attributes=values)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("display", ["range", "shape", "nan"])
def test_bad_display_writes_nothing(tmp_path, sources, display):
    surface = sources["arrays"]
    n = surface.n_vertices
    value = {"range": np.full((n, 3), 1.5), "shape": np.zeros(n), "nan": np.full((n, 3), np.nan)}[display]
    for name in ("out.ply", "out.usda", "out.gltf"):
        with pytest.raises(NumericalError):
            write_bake(tmp_path / name, surface, np.ones(n), display=value, color=True)
    assert list(tmp_path.iterdir()) == []


def test_gltf_names_that_clash_in_upper_case_are_refused(tmp_path, sources):
    surface = sources["arrays"]
    n = surface.n_vertices
    with pytest.raises(NumericalError, match="clash"):
        write_bake(tmp_path / "x.glb", surface, np.ones(n), attributes={"cav": np.ones(n), "CAV": np.ones(n)})
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["again.usda", "again.glb"])
def test_rebaking_an_output_replaces_its_attributes(tmp_path, sources, name):
    """A USD copy or glTF that already holds the attributes, baked again: the new values
    win (the overlay's opinions over the copy's, the glTF's new accessors)."""
    surface = sources["usd"] if name.endswith(".usda") else sources["gltf"]
    first = "copy.usdc" if name.endswith(".usda") else "first.glb"
    ao, attributes, _ = _values(surface.n_vertices)
    write_bake(tmp_path / first, surface, ao, attributes=attributes, **({"overlay": False} if first.endswith("c") else {}))
    again = load_mesh(tmp_path / first)
    ao2, attributes2, _ = _values(again.n_vertices, seed=4)
    write_bake(tmp_path / name, again, ao2, attributes=attributes2)
    if name.endswith(".usda"):
        got, _ = _read_usd(tmp_path / name, [p.prim_path for p in again.parts])
    else:
        got, _ = _read_gltf(tmp_path / name, again, False)
    for key, values in {"ao": ao2, **attributes2}.items():
        np.testing.assert_array_equal(got[key], np.asarray(values, dtype=np.float32), err_msg=key)
