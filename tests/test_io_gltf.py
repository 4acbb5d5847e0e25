"""glTF/GLB output: the input's own document with ``_AO`` per primitive, read back with
a plain decoder (tests/gltf_assets.py), pygltflib and trimesh; a new document for
other inputs."""

from __future__ import annotations

import json

import gltf_assets as ga
import numpy as np
import pygltflib
import pytest
import trimesh
from click.testing import CliRunner

from aobake.cli import main
from aobake.errors import InputError, OutputError
from aobake.io import load_mesh, read_bake, write_bake
from aobake.pipeline import bake_file
from aobake.testing import scenes

OPTS = dict(n_rays=32, seed=7, threads=1, effects="ao")  # the asset emits; these tests are of the AO (lit: test_light_bake)
#: part order of the scene: depth-first, children as listed (props lists box_b first)
PARTS = ["ground", "box_b", "tet", "box_a"]


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """The scene as .glb and .gltf, baked once to PLY (the reference values) and to glTF."""
    d = tmp_path_factory.mktemp("gltf")
    src = d / "src"
    src.mkdir()
    out = d / "out"
    out.mkdir()
    glb, gltf = ga.write_scene(src / "scene.glb"), ga.write_scene(src / "scene.gltf")
    bake_file(glb, out / "ref.ply", **OPTS)
    bake_file(glb, [out / "glb.glb", out / "glb.gltf"], **OPTS)
    bake_file(gltf, [out / "gltf.glb", out / "gltf.gltf"], color=True, **OPTS)
    return d, read_bake(out / "ref.ply"), load_mesh(glb)


def _part_ao(ref, surface, name):
    part = next(p for p in surface.parts if p.name == name)
    return ref[part.vertex_start : part.vertex_stop]


def test_parts_are_the_documents_primitives_in_scene_order(baked):
    _, ref, surface = baked
    assert [p.name for p in surface.parts] == PARTS
    assert ref.min() < 0.6 < ref.max()  # boxes on the ground: not a trivial bake


@pytest.mark.parametrize("name", ["glb.glb", "glb.gltf", "gltf.glb", "gltf.gltf"])
def test_ao_per_primitive_equals_the_ply_bake(baked, name):
    d, ref, surface = baked
    gl, blobs = ga.load(d / "out" / name)
    nodes = {n["name"]: n for n in gl["nodes"]}
    for part in PARTS:
        primitive = gl["meshes"][nodes[part]["mesh"]]["primitives"][0]
        ao = ga.accessor(gl, blobs, primitive["attributes"]["_AO"])
        assert gl["accessors"][primitive["attributes"]["_AO"]]["componentType"] == 5126  # float
        np.testing.assert_array_equal(ao[:, 0], _part_ao(ref, surface, part).astype(np.float32))
    # the point primitive is not baked and gets nothing
    assert set(gl["meshes"][0]["primitives"][1]["attributes"]) == {"POSITION"}


@pytest.mark.parametrize("name", ["glb.glb", "glb.gltf", "gltf.glb", "gltf.gltf"])
def test_document_kept_whole(baked, name):
    """Everything of the source is in the output unchanged; only accessors, buffer views,
    the instance's mesh copy and the new attributes are added."""
    d, _, _ = baked
    source = d / "src" / ("scene.glb" if name.startswith("glb") else "scene.gltf")
    src, src_blobs = ga.load(source)
    gl, blobs = ga.load(d / "out" / name)
    for key in ("scene", "scenes", "materials", "textures", "samplers", "extensionsUsed"):
        assert gl[key] == src[key], key
    assert (
        gl["asset"]["generator"] == src["asset"]["generator"] and gl["asset"]["extras"]["kept"] == 1
    )
    assert gl["asset"]["extras"]["aobake"]["method"] == "embree"
    # nodes: identical except that the second instance of the box uses its own mesh copy
    box_a = 2
    for i, (a, b) in enumerate(zip(gl["nodes"], src["nodes"], strict=True)):
        if i != box_a:
            assert a == b
    assert {k: v for k, v in gl["nodes"][box_a].items() if k != "mesh"} == {
        k: v for k, v in src["nodes"][box_a].items() if k != "mesh"
    }
    assert (
        gl["nodes"][box_a]["mesh"] == len(src["meshes"])
        and len(gl["meshes"]) == len(src["meshes"]) + 1
    )
    # every source accessor decodes to the same values (UVs, normals, colours, indices)
    for i in range(len(src["accessors"])):
        np.testing.assert_array_equal(ga.accessor(gl, blobs, i), ga.accessor(src, src_blobs, i))
    # primitives: the source's attributes and fields, plus _AO (and COLOR_0 with --color);
    # the asset has an emissive material, so the bake lights it: _IRRADIANCE too
    copy_of_box = gl["meshes"][-1]["primitives"][0]
    for mesh, src_mesh in zip(gl["meshes"], src["meshes"] + [src["meshes"][1]], strict=True):
        assert {k: v for k, v in mesh.items() if k != "primitives"} == {
            k: v for k, v in src_mesh.items() if k != "primitives"
        }
        for p, q in zip(mesh["primitives"], src_mesh["primitives"], strict=True):
            assert {k: v for k, v in p.items() if k != "attributes"} == {
                k: v for k, v in q.items() if k != "attributes"
            }
            added = set(p["attributes"]) - set(q["attributes"])
            assert added <= {"_AO", "COLOR_0", "_IRRADIANCE"}
            for key in q["attributes"]:
                if key != "COLOR_0" or not name.startswith("gltf"):
                    assert p["attributes"][key] == q["attributes"][key]
    assert (
        copy_of_box["attributes"]["POSITION"]
        == src["meshes"][1]["primitives"][0]["attributes"]["POSITION"]
    )
    assert ga.image_bytes(d / "out" / name, gl, blobs) == ga.TEXTURE


def test_instances_get_their_own_ao(baked):
    d, ref, surface = baked
    gl, blobs = ga.load(d / "out" / "glb.glb")
    a = ga.accessor(
        gl, blobs, gl["meshes"][gl["nodes"][2]["mesh"]]["primitives"][0]["attributes"]["_AO"]
    )
    b = ga.accessor(
        gl, blobs, gl["meshes"][gl["nodes"][3]["mesh"]]["primitives"][0]["attributes"]["_AO"]
    )
    assert not np.array_equal(a, b)  # the two boxes stand differently on the ground
    np.testing.assert_array_equal(a[:, 0], _part_ao(ref, surface, "box_a").astype(np.float32))


def test_glb_is_self_contained_and_gltf_refers_to_the_source_files(baked):
    d, _, _ = baked
    glb, _ = ga.load(d / "out" / "gltf.glb")
    assert all("uri" not in b for b in glb["buffers"]) and "uri" not in glb["images"][0]
    assert glb["images"][0]["mimeType"] == "image/png"
    gltf = json.loads((d / "out" / "gltf.gltf").read_text())
    assert gltf["buffers"][0]["uri"] == "../src/scene.bin"
    assert gltf["images"][0]["uri"] == "../src/tex%20ture.png"
    assert gltf["buffers"][-1]["uri"].startswith("data:application/octet-stream;base64,")


def test_color_is_linear_grey(baked):
    d, ref, surface = baked
    gl, blobs = ga.load(d / "out" / "gltf.gltf")
    for node in gl["nodes"]:
        if "mesh" in node:
            attributes = gl["meshes"][node["mesh"]]["primitives"][0]["attributes"]
            colors = ga.accessor(gl, blobs, attributes["COLOR_0"])
            assert colors.shape[1] == 3 and colors.dtype == np.float32
            np.testing.assert_array_equal(
                colors, np.repeat(ga.accessor(gl, blobs, attributes["_AO"]), 3, axis=1)
            )


def test_pygltflib_and_trimesh_read_the_output(baked):
    d, ref, surface = baked
    doc = pygltflib.GLTF2().load(str(d / "out" / "glb.glb"))
    assert [n.name for n in doc.nodes] == ["ground", "props", "box_a", "box_b", "tet"]
    assert doc.materials[1].extensions == {
        "KHR_materials_emissive_strength": {"emissiveStrength": 2.0}
    }
    assert doc.nodes[3].extensions == {"EXT_test_unknown": {"x": 1}}
    scene = trimesh.load(d / "out" / "glb.glb", process=False)
    meshes = {k: g for k, g in scene.geometry.items() if isinstance(g, trimesh.Trimesh)}
    tet = meshes["tet"]
    np.testing.assert_array_equal(
        tet.vertex_attributes["_AO"].ravel(), _part_ao(ref, surface, "tet").astype(np.float32)
    )
    # re-reading the output gives the same surface as the source
    again = load_mesh(d / "out" / "glb.glb")
    np.testing.assert_allclose(again.positions, surface.positions, atol=1e-6)


def test_channel_packs_into_each_primitives_own_colours(tmp_path):
    src = ga.write_scene(tmp_path / "c.glb", colored_everywhere=True)
    ao = np.linspace(0, 1, load_mesh(src).n_vertices)
    surface = load_mesh(src)
    write_bake(tmp_path / "o.glb", surface, ao, channel="A")
    gl, blobs = ga.load(tmp_path / "o.glb")
    before, before_blobs = ga.load(src)
    for part in surface.parts:
        node = next(n for n in gl["nodes"] if n["name"] == part.name)
        mesh = gl["meshes"][node["mesh"]]
        source_mesh = before["meshes"][
            next(n for n in before["nodes"] if n["name"] == part.name)["mesh"]
        ]
        old = ga.accessor(
            before, before_blobs, source_mesh["primitives"][0]["attributes"]["COLOR_0"]
        )
        index = mesh["primitives"][0]["attributes"]["COLOR_0"]
        new = ga.accessor(gl, blobs, index)
        values = ao[part.vertex_start : part.vertex_stop]
        assert new.dtype == old.dtype and new.shape[1] == 4
        np.testing.assert_array_equal(new[:, :3], old[:, :3])  # other channels bit-identical
        if new.dtype == np.uint8:
            assert gl["accessors"][index]["normalized"] is True
            np.testing.assert_array_equal(new[:, 3], np.rint(values * 255))
        else:
            np.testing.assert_array_equal(new[:, 3], values.astype(np.float32))


def test_channel_needs_colours_on_every_primitive(tmp_path):
    src = ga.write_scene(tmp_path / "s.glb")
    out = tmp_path / "o.glb"
    result = CliRunner().invoke(
        main, ["bake", str(src), "-o", str(out), "--rays", "4", "--channel", "R"]
    )
    assert result.exit_code == 1
    assert (
        result.output.strip()
        == "Error: s.glb: --channel R: 2 primitives have no vertex colours (COLOR_0)"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.glb"]


def test_other_inputs_become_a_new_document(tmp_path):
    s = scenes.sphere_on_plane(subdivisions=1, cells=2)
    ao = np.linspace(0, 1, s.n_vertices)
    for up in ("Y", "Z"):
        out = tmp_path / f"new_{up}.glb"
        write_bake(
            out, s, ao, color=True, up_axis=up, meters_per_unit=0.01, custom_data={"method": "x"}
        )
        scene = trimesh.load(out, process=False)
        placed = []
        for part in s.parts:  # trimesh places each node's geometry
            matrix, geometry = scene.graph[part.name]
            placed.append(trimesh.transform_points(scene.geometry[geometry].vertices, matrix))
        positions = np.concatenate(placed)
        expected = s.positions * 0.01
        if up == "Z":  # turned so that the input's +Z is glTF's +Y
            expected = np.c_[expected[:, 0], expected[:, 2], -expected[:, 1]]
        np.testing.assert_allclose(positions, expected, atol=1e-7)
        gl, blobs = ga.load(out)
        got = np.concatenate(
            [
                ga.accessor(gl, blobs, m["primitives"][0]["attributes"]["_AO"])[:, 0]
                for m in gl["meshes"]
            ]
        )
        np.testing.assert_array_equal(got, ao.astype(np.float32))
        faces = np.concatenate(
            [
                ga.accessor(gl, blobs, m["primitives"][0]["indices"]).reshape(-1, 3)
                + p.vertex_start
                for m, p in zip(gl["meshes"], s.parts, strict=True)
            ]  # fmt: skip
        )
        np.testing.assert_array_equal(faces, s.faces)


def test_channel_for_a_new_document_is_refused(tmp_path):
    s = scenes.box()
    with pytest.raises(InputError, match="no vertex colours"):
        write_bake(tmp_path / "o.gltf", s, np.ones(s.n_vertices), channel="R")
    assert list(tmp_path.iterdir()) == []


def test_ply_to_gltf_via_cli_and_deterministic(tmp_path):
    s = scenes.box()
    trimesh.Trimesh(s.positions, s.faces, process=False).export(tmp_path / "b.ply")
    for k in (1, 2):
        result = CliRunner().invoke(
            main,
            [
                "bake",
                str(tmp_path / "b.ply"),
                "-o",
                str(tmp_path / f"o{k}.gltf"),
                "--rays",
                "8",
                "-q",
            ],
        )
        assert result.exit_code == 0, result.output
    assert (tmp_path / "o1.gltf").read_bytes() == (tmp_path / "o2.gltf").read_bytes()
    gl, blobs = ga.load(tmp_path / "o1.gltf")
    np.testing.assert_array_equal(
        ga.accessor(gl, blobs, gl["meshes"][0]["primitives"][0]["attributes"]["_AO"]), 1.0
    )


def test_read_bake_compare_and_preview_take_gltf(baked, tmp_path):
    d, ref, _ = baked
    for name in ("glb.glb", "gltf.gltf"):
        np.testing.assert_array_equal(read_bake(d / "out" / name), ref.astype(np.float32))
    result = CliRunner().invoke(
        main, ["compare", str(d / "out" / "ref.ply"), str(d / "out" / "glb.glb")]
    )
    assert result.exit_code == 0 and "RMSE" in result.output and "0.000000" in result.output
    result = CliRunner().invoke(
        main, ["preview", str(d / "out" / "glb.glb"), "-o", str(tmp_path / "p.png"), "--size", "32"]
    )
    assert result.exit_code == 0 and (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(InputError, match="s.glb: node 'ground' has a primitive without _AO"):
        read_bake(ga.write_scene(tmp_path / "s.glb"))


def test_interleaved_attributes_and_strips(tmp_path):
    """POSITION and NORMAL interleaved in one strided view, the box drawn as a triangle
    strip: found, baked, and left as they were."""
    gl, data = ga.scene_document()
    p = ga.accessor(gl, [data], gl["meshes"][0]["primitives"][0]["attributes"]["POSITION"])
    n = ga.accessor(gl, [data], gl["meshes"][0]["primitives"][0]["attributes"]["NORMAL"])
    interleaved = np.hstack([p, n]).astype(np.float32).tobytes()
    start = len(data) + (-len(data) % 4)
    data = data + b"\0" * (start - len(data)) + interleaved
    gl["bufferViews"].append(
        {"buffer": 0, "byteOffset": start, "byteLength": len(interleaved), "byteStride": 24}
    )
    view = len(gl["bufferViews"]) - 1
    position = dict(gl["accessors"][0], bufferView=view)
    normal = dict(gl["accessors"][1], bufferView=view, byteOffset=12)
    normal.pop("min", None), normal.pop("max", None)
    gl["accessors"] += [position, normal]
    gl["meshes"][0]["primitives"][0]["attributes"].update(
        POSITION=len(gl["accessors"]) - 2, NORMAL=len(gl["accessors"]) - 1
    )
    strip = np.array(
        [0, 1, 3, 2], np.uint16
    )  # the quad as a strip: triangles 0 1 3, 3 1 2 (flipped)
    start = len(data) + (-len(data) % 4)
    data = data + b"\0" * (start - len(data)) + strip.tobytes()
    gl["bufferViews"].append({"buffer": 0, "byteOffset": start, "byteLength": strip.nbytes})
    gl["accessors"].append(
        {
            "bufferView": len(gl["bufferViews"]) - 1,
            "componentType": 5123,
            "count": 4,
            "type": "SCALAR",
        }
    )
    gl["meshes"][0]["primitives"][0].update(indices=len(gl["accessors"]) - 1, mode=5)
    gl["buffers"][0]["byteLength"] = len(data)
    del gl["images"][0]  # no texture in this one
    gl["textures"] = []
    gl["materials"][0] = {"name": "plain"}
    gl["buffers"][0]["uri"] = (
        "data:application/octet-stream;base64," + __import__("base64").b64encode(data).decode()
    )
    src = tmp_path / "strided.gltf"
    src.write_text(json.dumps(gl))
    bake_file(src, [tmp_path / "o.glb", tmp_path / "o.ply"], n_rays=16, seed=2, threads=1)
    out, blobs = ga.load(tmp_path / "o.glb")
    ground = out["meshes"][0]["primitives"][0]
    np.testing.assert_array_equal(ga.accessor(out, blobs, ground["attributes"]["NORMAL"]), n)
    assert (
        out["bufferViews"][out["accessors"][ground["attributes"]["POSITION"]]["bufferView"]][
            "byteStride"
        ]
        == 24
    )
    ao = ga.accessor(out, blobs, ground["attributes"]["_AO"])[:, 0]
    np.testing.assert_array_equal(ao, read_bake(tmp_path / "o.ply")[:4].astype(np.float32))


def test_a_surface_that_is_not_the_document_is_refused(tmp_path):
    import dataclasses

    src = ga.write_scene(tmp_path / "s.glb")
    surface = load_mesh(src)
    moved = dataclasses.replace(surface, positions=surface.positions + 1.0)
    with pytest.raises(
        OutputError, match="mesh 'ground' matches no primitive of the glTF document"
    ):
        write_bake(tmp_path / "o.glb", moved, np.ones(surface.n_vertices))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.glb"]


def test_a_document_changed_since_loading_is_refused_before_baking(tmp_path, monkeypatch):
    """The check runs before the bake: a document whose meshes moved since loading (here:
    the loaded surface is shifted) fails at once, with nothing written."""
    import aobake.pipeline as pipeline

    src = ga.write_scene(tmp_path / "s.glb")
    real = pipeline.as_surface

    def shifted(source, *args, **kwargs):
        import dataclasses

        surface = real(source, *args, **kwargs)
        return dataclasses.replace(surface, positions=surface.positions + 1.0)

    def no_bake(*args, **kwargs):
        raise AssertionError("baked before checking the outputs")

    monkeypatch.setattr(pipeline, "as_surface", shifted)
    monkeypatch.setattr(pipeline, "_compute", no_bake)
    with pytest.raises(OutputError, match="matches no primitive"):
        bake_file(src, [tmp_path / "o.ply", tmp_path / "o.glb"], n_rays=4)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.glb"]


def test_missing_image_is_refused_before_baking_a_glb(tmp_path):
    src = ga.write_scene(tmp_path / "s.gltf")
    (tmp_path / "tex ture.png").unlink()
    runner = CliRunner()
    result = runner.invoke(main, ["bake", str(src), "-o", str(tmp_path / "o.glb"), "--rays", "4"])
    assert result.exit_code == 1
    assert (
        result.output
        == "Error: s.gltf: image 'tex%20ture.png' not found; a GLB output embeds its images\n"
    )
    assert not (tmp_path / "o.glb").exists()
    # a .gltf output refers to the file where it was, as the input did
    result = runner.invoke(
        main, ["bake", str(src), "-o", str(tmp_path / "o.gltf"), "--rays", "4", "-q"]
    )
    assert result.exit_code == 0, result.output
