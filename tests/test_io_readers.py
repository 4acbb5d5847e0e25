"""Reading meshes: ``aobake.io.load_mesh`` over every format (PLY, OBJ, STL, OFF, glTF/GLB,
USD) and ``mesh_from_trimesh``; bad files give one-line InputErrors naming the file.

Files are written here by independent means where practical (plyfile, plain text,
numpy-packed binary STL, pxr); only glTF/GLB is authored with trimesh.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aobake.errors import InputError
from aobake.io import load_mesh
from aobake.io.trimesh_formats import mesh_from_trimesh
from aobake.mesh import angle_weighted_normals

# A mesh with the awkward but legal features a loader must not "fix":
# vertex 3 duplicates vertex 1, vertex 4 (middle) and 7 (last) are unreferenced,
# face 2 has zero area (vertex 6 lies on the edge 1-2). All values exact in float32.
POSITIONS = np.array(
    [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [5.0, 5.0, 5.0],
        [1.0, 1.0, 0.0],
        [0.5, 0.5, 0.0],
        [9.0, 9.0, 9.0],
    ]
)
FACES = np.array([[0, 1, 2], [3, 5, 2], [1, 6, 2]])


# -- writers -----------------------------------------------------------------------------


def write_ply(path, positions, faces, normals=None, text=False, byte_order="<"):
    from plyfile import PlyData, PlyElement

    fields = [("x", "f4"), ("y", "f4"), ("z", "f4")]
    if normals is not None:
        fields += [("nx", "f4"), ("ny", "f4"), ("nz", "f4")]
    vertex = np.zeros(len(positions), dtype=fields)
    for i, axis in enumerate("xyz"):
        vertex[axis] = positions[:, i]
        if normals is not None:
            vertex["n" + axis] = normals[:, i]
    face = np.zeros(len(faces), dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = faces
    elements = [PlyElement.describe(vertex, "vertex"), PlyElement.describe(face, "face")]
    PlyData(elements, text=text, byte_order=byte_order).write(str(path))
    return path


def write_obj(path, positions, faces, normals=None):
    lines = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in positions]
    if normals is None:
        lines += ["f " + " ".join(str(i + 1) for i in f) for f in faces]
    else:
        lines += [f"vn {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in normals]
        lines += ["f " + " ".join(f"{i + 1}//{i + 1}" for i in f) for f in faces]
    path.write_text("# test\n" + "\n".join(lines) + "\n")
    return path


def write_off(path, positions, faces):
    lines = ["OFF", f"{len(positions)} {len(faces)} 0"]
    lines += [f"{float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in positions]
    lines += [f"{len(f)} " + " ".join(map(str, f)) for f in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_stl(path, positions, faces):
    record = np.zeros(
        len(faces), dtype=[("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attr", "<u2")]
    )
    record["corners"] = positions[faces]
    path.write_bytes(b"\0" * 80 + np.uint32(len(faces)).tobytes() + record.tobytes())
    return path


def write_glb(path, positions, faces):
    """GLB, or with a .gltf suffix a JSON file plus .bin buffers beside it."""
    import trimesh

    trimesh.Trimesh(positions, faces, process=False).export(str(path))
    return path


def write_usd(path, positions, faces):
    from pxr import Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    mesh = UsdGeom.Mesh.Define(stage, "/awkward")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(positions, dtype=np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([len(f) for f in faces]))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([int(i) for f in faces for i in f]))
    stage.GetRootLayer().Save()
    return path


# file name -> writer; the same mesh in every format and encoding load_mesh reads
WRITERS = {
    "binary.ply": write_ply,
    "ascii.ply": lambda p, v, f: write_ply(p, v, f, text=True),
    "big.ply": lambda p, v, f: write_ply(p, v, f, byte_order=">"),
    "awkward.obj": write_obj,
    "awkward.off": write_off,
    "awkward.glb": write_glb,
    "awkward.gltf": write_glb,
    "awkward.usda": write_usd,
    "awkward.usdc": write_usd,
}


# -- topology is preserved ------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(WRITERS))
def test_vertices_kept_exactly(tmp_path, name):
    if name.endswith((".usda", ".usdc")):
        pytest.importorskip("pxr")
    path = WRITERS[name](tmp_path / name, POSITIONS, FACES)
    surface = load_mesh(path)
    np.testing.assert_array_equal(surface.positions, POSITIONS)
    np.testing.assert_array_equal(surface.faces, FACES)
    assert surface.positions.dtype == np.float64 and surface.faces.dtype == np.int64
    assert np.isfinite(surface.normals).all()
    # no file normals: angle-weighted; vertex 6 (only in the zero-area face) and the
    # unreferenced vertices have none
    np.testing.assert_allclose(
        surface.normals[[0, 1, 2, 3, 5]], np.tile([0.0, 0.0, 1.0], (5, 1)), atol=1e-15
    )
    np.testing.assert_array_equal(surface.normals[[4, 6, 7]], np.zeros((3, 3)))
    assert surface.source == path.name
    (part,) = surface.parts
    assert (part.vertex_start, part.vertex_stop, part.face_start, part.face_stop) == (0, 8, 0, 3)


def test_stl_has_three_vertices_per_face(tmp_path):
    surface = load_mesh(write_stl(tmp_path / "awkward.stl", POSITIONS, FACES))
    assert surface.n_vertices == 3 * len(FACES)
    np.testing.assert_array_equal(surface.positions, POSITIONS[FACES].reshape(-1, 3))
    np.testing.assert_array_equal(surface.faces, np.arange(9).reshape(3, 3))
    assert surface.parts[0].name == "awkward"


def test_missing_normal_is_warned(tmp_path, caplog):
    with caplog.at_level(logging.WARNING, logger="aobake.mesh"):
        load_mesh(write_ply(tmp_path / "awkward.ply", POSITIONS, FACES))
    assert "awkward.ply: 1 vertices have no defined normal" in caplog.text


def test_polygons_fan_triangulated_and_kept(tmp_path):
    path = tmp_path / "quad.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nf 1 2 3 4\nf 2 5 3\n")
    surface = load_mesh(path)
    np.testing.assert_array_equal(surface.faces, [[0, 1, 2], [0, 2, 3], [1, 4, 2]])
    np.testing.assert_array_equal(surface.parts[0].face_vertex_counts, [4, 3])
    np.testing.assert_array_equal(surface.parts[0].face_vertex_indices, [0, 1, 2, 3, 1, 4, 2])


def test_obj_negative_indices_and_slashes(tmp_path):
    path = tmp_path / "rel.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf -3/1 -2/1 -1/1\n")
    np.testing.assert_array_equal(load_mesh(path).faces, [[0, 1, 2]])


def test_obj_negative_indices_count_from_the_face_line(tmp_path):
    # -1 is the last vertex listed before the face, not the last of the file
    path = tmp_path / "rel.obj"
    path.write_text(
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nf -4//-1 -3//-1 -2//-1 -1//-1\n"
        "v 2 0 0\nf -4 -1 -3\n"
    )
    surface = load_mesh(path)
    part = surface.parts[0]
    np.testing.assert_array_equal(part.face_vertex_counts, [4, 3])
    np.testing.assert_array_equal(part.face_vertex_indices, [0, 1, 2, 3, 1, 4, 2])
    np.testing.assert_array_equal(surface.faces, [[0, 1, 2], [0, 2, 3], [1, 4, 2]])
    np.testing.assert_array_equal(surface.normals[:4], np.tile([0.0, 0.0, 1.0], (4, 1)))


# -- normals from the file --------------------------------------------------------------


def _wrong_unit_normals(n):
    rng = np.random.default_rng(0)
    normals = rng.normal(size=(n, 3))
    return (normals / np.linalg.norm(normals, axis=1, keepdims=True)).astype(np.float32)


@pytest.mark.parametrize("text", [False, True])
def test_ply_file_normals_used(tmp_path, text):
    normals = _wrong_unit_normals(len(POSITIONS))
    surface = load_mesh(write_ply(tmp_path / "n.ply", POSITIONS, FACES, normals, text=text))
    np.testing.assert_allclose(surface.normals, normals, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(surface.normals, axis=1), 1.0, atol=1e-12)


def test_obj_file_normals_used(tmp_path):
    normals = _wrong_unit_normals(len(POSITIONS)).astype(np.float64)
    surface = load_mesh(write_obj(tmp_path / "n.obj", POSITIONS, FACES, normals))
    used = np.unique(FACES)
    np.testing.assert_allclose(surface.normals[used], normals[used], atol=1e-12)
    # unreferenced vertices get no normal from vn, and none can be computed
    np.testing.assert_array_equal(surface.normals[[4, 7]], np.zeros((2, 3)))


def test_zero_file_normal_falls_back(tmp_path):
    normals = _wrong_unit_normals(len(POSITIONS))
    normals[0] = 0.0
    surface = load_mesh(write_ply(tmp_path / "z.ply", POSITIONS, FACES, normals))
    np.testing.assert_allclose(surface.normals[0], [0.0, 0.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(surface.normals[1:], normals[1:], atol=1e-6)


def test_no_file_normals_are_angle_weighted(tmp_path):
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=1)
    positions, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    surface = load_mesh(write_ply(tmp_path / "s.ply", positions, faces))
    p32 = positions.astype(np.float32).astype(np.float64)
    np.testing.assert_array_equal(surface.normals, angle_weighted_normals(p32, faces))


# -- PLY details (read by aobake, not trimesh) ------------------------------------------


def write_polygon_ply(path, text=False, byte_order="<"):
    """Binary or ASCII PLY with mixed polygon sizes, colours and an extra element."""
    from plyfile import PlyData, PlyElement

    vertex = np.zeros(6, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1")])
    vertex["x"] = [0, 1, 1, 0, 2, 3]
    vertex["y"] = [0, 0, 1, 1, 0, 1]
    face = np.empty(3, dtype=[("vertex_indices", "O"), ("flag", "i2")])
    face["vertex_indices"] = [np.array(f, "i4") for f in ([0, 1, 2, 3], [1, 4, 2], [1, 4, 5, 2, 0])]
    face["flag"] = [7, 8, 9]
    edge = np.zeros(2, dtype=[("vertex1", "i4"), ("vertex2", "i4")])
    elements = [
        PlyElement.describe(a, n) for a, n in ((vertex, "vertex"), (face, "face"), (edge, "edge"))
    ]
    PlyData(elements, text=text, byte_order=byte_order).write(str(path))
    return path


@pytest.mark.parametrize("text, byte_order", [(False, "<"), (False, ">"), (True, "=")])
def test_ply_mixed_polygons(tmp_path, text, byte_order):
    # trimesh 5.2 reads the binary variant as garbage faces
    surface = load_mesh(write_polygon_ply(tmp_path / "poly.ply", text, byte_order))
    assert surface.n_vertices == 6
    np.testing.assert_array_equal(surface.parts[0].face_vertex_counts, [4, 3, 5])
    np.testing.assert_array_equal(
        surface.parts[0].face_vertex_indices, [0, 1, 2, 3, 1, 4, 2, 1, 4, 5, 2, 0]
    )
    np.testing.assert_array_equal(
        surface.faces, [[0, 1, 2], [0, 2, 3], [1, 4, 2], [1, 4, 5], [1, 5, 2], [1, 2, 0]]
    )


@st.composite
def polygon_meshes(draw):
    """Small meshes of mixed polygon sizes; coordinates exact in float32."""
    n = draw(st.integers(1, 10))
    coords = draw(st.lists(st.integers(-64, 64), min_size=3 * n, max_size=3 * n))
    positions = np.array(coords, dtype=np.float64).reshape(n, 3) / 8.0
    polygons = draw(
        st.lists(st.lists(st.integers(0, n - 1), min_size=3, max_size=6), min_size=1, max_size=8)
    )
    return positions, polygons


@settings(max_examples=40, deadline=None)
@given(mesh=polygon_meshes(), kind=st.sampled_from(["binary", "big", "ascii", "obj"]))
def test_polygon_files_round_trip(tmp_path_factory, mesh, kind):
    from plyfile import PlyData, PlyElement

    positions, polygons = mesh
    path = tmp_path_factory.mktemp("poly") / ("m.obj" if kind == "obj" else "m.ply")
    if kind == "obj":
        lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in positions.tolist()]
        lines += ["f " + " ".join(str(i + 1) for i in poly) for poly in polygons]
        path.write_text("\n".join(lines) + "\n")
    else:
        vertex = np.zeros(len(positions), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
        for i, axis in enumerate("xyz"):
            vertex[axis] = positions[:, i]
        face = np.empty(len(polygons), dtype=[("vertex_indices", "O")])
        face["vertex_indices"] = [np.array(poly, dtype="i4") for poly in polygons]
        elements = [PlyElement.describe(vertex, "vertex"), PlyElement.describe(face, "face")]
        order = ">" if kind == "big" else "<"
        PlyData(elements, text=kind == "ascii", byte_order=order).write(str(path))
    surface = load_mesh(path)
    np.testing.assert_array_equal(surface.positions, positions)
    (part,) = surface.parts
    np.testing.assert_array_equal(part.face_vertex_counts, [len(poly) for poly in polygons])
    np.testing.assert_array_equal(part.face_vertex_indices, np.concatenate(polygons))
    fan = [[poly[0], poly[k], poly[k + 1]] for poly in polygons for k in range(1, len(poly) - 1)]
    np.testing.assert_array_equal(surface.faces, fan)
    assert np.isfinite(surface.normals).all()


def test_ply_truncated_ascii(tmp_path):
    # trimesh 5.2 loads this as a smaller mesh without complaint
    path = write_ply(tmp_path / "cut.ply", POSITIONS, FACES, text=True)
    text = path.read_text()
    path.write_text(text[: text.index("end_header") + 40])
    with pytest.raises(
        InputError, match=r"^cut.ply: cannot read as PLY: file ends before its 8 vertex elements"
    ):
        load_mesh(path)


# -- scenes: several meshes, transforms --------------------------------------------------


def _two_mesh_scene():
    import trimesh

    tri = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    quad = trimesh.Trimesh(
        [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [3, 3, 3]],
        [[0, 1, 2], [0, 2, 3]],
        process=False,
    )
    # rotate 90 degrees about x (the normal +z becomes -y), then move by (10, 0, 0)
    matrix = trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0])
    matrix[:3, 3] = [10.0, 0.0, 0.0]
    scene = trimesh.Scene()
    scene.add_geometry(quad, node_name="moved", geom_name="quad", transform=matrix)
    scene.add_geometry(tri, node_name="still", geom_name="tri")
    return scene, matrix


def _check_two_mesh_surface(surface, matrix):
    assert [p.name for p in surface.parts] == ["moved", "still"]
    moved, still = surface.parts
    assert (moved.vertex_start, moved.vertex_stop, moved.face_start, moved.face_stop) == (
        0,
        5,
        0,
        2,
    )
    assert (still.vertex_start, still.vertex_stop, still.face_start, still.face_stop) == (
        5,
        8,
        2,
        3,
    )
    local = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [3, 3, 3]], float)
    world = local @ matrix[:3, :3].T + matrix[:3, 3]
    np.testing.assert_allclose(surface.positions[:5], world, atol=1e-6)
    np.testing.assert_allclose(surface.positions[5:], [[0, 0, 0], [1, 0, 0], [0, 1, 0]], atol=0)
    np.testing.assert_array_equal(surface.faces, [[0, 1, 2], [0, 2, 3], [5, 6, 7]])
    np.testing.assert_array_equal(still.face_vertex_indices, [0, 1, 2])
    np.testing.assert_allclose(surface.normals[:4], np.tile([0.0, -1.0, 0.0], (4, 1)), atol=1e-6)
    np.testing.assert_allclose(surface.normals[5:], np.tile([0.0, 0.0, 1.0], (3, 1)), atol=1e-15)


def test_glb_scene_flattened_in_file_order(tmp_path):
    scene, matrix = _two_mesh_scene()
    path = tmp_path / "two.glb"
    scene.export(str(path))
    _check_two_mesh_surface(load_mesh(path), matrix)


def test_trimesh_scene_flattened(tmp_path):
    scene, matrix = _two_mesh_scene()
    surface = mesh_from_trimesh(scene, source="scene")
    _check_two_mesh_surface(surface, matrix)
    assert surface.source == "scene"


def write_gltf_hierarchy(path):
    """A .gltf (embedded buffer) with a parent node, children listed out of index order,
    a two-primitive mesh and a translated node."""
    import base64
    import json

    tris = [np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32) + k for k in range(3)]
    blob = b"".join(t.tobytes() for t in tris) + np.array([0, 1, 2], np.uint32).tobytes()
    views = [{"buffer": 0, "byteOffset": 36 * k, "byteLength": 36} for k in range(3)]
    views.append({"buffer": 0, "byteOffset": 108, "byteLength": 12})
    accessors = [
        {"bufferView": k, "componentType": 5126, "count": 3, "type": "VEC3",
         "min": tris[k].min(0).tolist(), "max": tris[k].max(0).tolist()}
        for k in range(3)
    ]  # fmt: skip
    accessors.append({"bufferView": 3, "componentType": 5125, "count": 3, "type": "SCALAR"})
    document = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [
            {"name": "root", "children": [2, 1]},
            {"name": "b", "mesh": 1, "translation": [0, 0, 5]},
            {"name": "a", "mesh": 0},
        ],
        "meshes": [
            {"name": "m0", "primitives": [{"attributes": {"POSITION": 0}, "indices": 3},
                                          {"attributes": {"POSITION": 1}, "indices": 3}]},
            {"name": "m1", "primitives": [{"attributes": {"POSITION": 2}, "indices": 3}]},
        ],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:;base64," + base64.b64encode(blob).decode()}],
    }  # fmt: skip
    path.write_text(json.dumps(document))
    return path


def test_gltf_hierarchy_in_file_order(tmp_path):
    # trimesh lists the nodes b, a, a (depth-first from the last child); the file order is a, a, b
    surface = load_mesh(write_gltf_hierarchy(tmp_path / "tree.gltf"))
    assert [(p.name, p.vertex_start, p.vertex_stop) for p in surface.parts] == [
        ("m0", 0, 3),
        ("m0_1", 3, 6),
        ("b", 6, 9),
    ]
    expected = np.concatenate([np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]) + k for k in range(3)])
    expected[6:, 2] += 5.0
    np.testing.assert_array_equal(surface.positions, expected)
    assert surface.metadata["up_axis"] == "Y"


def test_glb_normals_rotated(tmp_path):
    import trimesh

    normals = np.tile([0.0, 0.0, 1.0], (3, 1))  # deliberately +z everywhere
    tri = trimesh.Trimesh(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], vertex_normals=normals, process=False
    )
    scene = trimesh.Scene()
    scene.add_geometry(
        tri, node_name="n", transform=trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0])
    )
    scene.export(str(tmp_path / "n.glb"))
    surface = load_mesh(tmp_path / "n.glb")
    np.testing.assert_allclose(surface.normals, np.tile([1.0, 0.0, 0.0], (3, 1)), atol=1e-6)


def test_mirror_transform_keeps_winding_outward():
    import trimesh

    box = trimesh.creation.box()
    box = trimesh.Trimesh(box.vertices + [2.0, 0, 0], box.faces, process=False)
    scene = trimesh.Scene()
    scene.add_geometry(box, node_name="mirrored", transform=np.diag([-1.0, 1.0, 1.0, 1.0]))
    surface = mesh_from_trimesh(scene)
    centre = surface.positions.mean(axis=0)
    outward = np.einsum("ij,ij->i", surface.normals, surface.positions - centre)
    assert (outward > 0).all()
    np.testing.assert_array_equal(surface.faces, np.asarray(box.faces)[:, ::-1])


def test_trimesh_point_cloud_ignored():
    import trimesh

    scene, matrix = _two_mesh_scene()
    scene.add_geometry(trimesh.PointCloud(np.zeros((4, 3))), node_name="points")
    _check_two_mesh_surface(mesh_from_trimesh(scene), matrix)


def test_trimesh_mesh_direct():
    import trimesh

    box = trimesh.creation.box()
    surface = mesh_from_trimesh(box)
    np.testing.assert_array_equal(surface.positions, box.vertices)
    np.testing.assert_array_equal(surface.faces, box.faces)
    with pytest.raises(TypeError):
        mesh_from_trimesh(np.zeros((3, 3)))


def test_obj_objects_become_parts(tmp_path):
    path = tmp_path / "two.obj"
    path.write_text(
        "o first\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
        "o second\nv 0 0 1\nv 1 0 1\nv 0 1 1\nv 8 8 8\nf 4 5 6\n"
    )
    surface = load_mesh(path)
    assert [
        (p.name, p.vertex_start, p.vertex_stop, p.face_start, p.face_stop) for p in surface.parts
    ] == [
        ("first", 0, 3, 0, 1),
        ("second", 3, 7, 1, 2),
    ]
    np.testing.assert_array_equal(surface.parts[1].face_vertex_indices, [0, 1, 2])
    np.testing.assert_array_equal(surface.faces, [[0, 1, 2], [3, 4, 5]])


def test_obj_objects_sharing_vertices_stay_one_part(tmp_path):
    path = tmp_path / "shared.obj"
    path.write_text("o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\no b\nv 0 0 1\nf 1 2 4\n")
    surface = load_mesh(path)
    assert len(surface.parts) == 1 and surface.parts[0].n_vertices == 4


# -- USD ---------------------------------------------------------------------------------


def _author_usd(path, *, normals=None, interpolation="vertex"):
    from pxr import Gf, Sdf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    xform = UsdGeom.Xform.Define(stage, "/World")
    xform.AddTranslateOp().Set(Gf.Vec3d(1.0, 2.0, 3.0))
    xform.AddRotateZOp().Set(90.0)
    mesh = UsdGeom.Mesh.Define(stage, "/World/Plate")
    points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0)]
    mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in points]))
    # a quad, a triangle and a two-corner "polygon" that tracing must drop
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([4, 3, 2]))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([0, 1, 2, 3, 1, 4, 2, 0, 4]))
    if normals is not None:
        primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
            "normals", Sdf.ValueTypeNames.Normal3fArray, getattr(UsdGeom.Tokens, interpolation)
        )
        primvar.Set(Vt.Vec3fArray([Gf.Vec3f(*n) for n in normals]))
    hidden = UsdGeom.Mesh.Define(stage, "/World/Hidden")
    hidden.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(0, 0, 0)] * 3))
    hidden.CreateFaceVertexCountsAttr(Vt.IntArray([3]))
    hidden.CreateFaceVertexIndicesAttr(Vt.IntArray([0, 1, 2]))
    hidden.MakeInvisible()
    stage.GetRootLayer().Save()
    return path


@pytest.mark.parametrize("suffix", ["usda", "usdc"])
def test_usd_quad_mesh_world_space(tmp_path, suffix):
    surface = load_mesh(_author_usd(tmp_path / f"plate.{suffix}"))
    (part,) = surface.parts
    assert part.name == "Plate" and part.prim_path == "/World/Plate"
    np.testing.assert_array_equal(part.face_vertex_counts, [4, 3, 2])
    np.testing.assert_array_equal(part.face_vertex_indices, [0, 1, 2, 3, 1, 4, 2, 0, 4])
    np.testing.assert_array_equal(surface.faces, [[0, 1, 2], [0, 2, 3], [1, 4, 2]])
    # rotate 90 degrees about z, then translate: (x, y, z) -> (1 - y, 2 + x, 3 + z)
    local = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0)], float)
    world = np.column_stack([1.0 - local[:, 1], 2.0 + local[:, 0], 3.0 + local[:, 2]])
    np.testing.assert_allclose(surface.positions, world, atol=1e-12)
    np.testing.assert_allclose(surface.normals, np.tile([0.0, 0.0, 1.0], (5, 1)), atol=1e-12)
    assert surface.metadata["up_axis"] == "Z"
    assert surface.metadata["meters_per_unit"] == pytest.approx(0.01)


def test_usd_vertex_normals_used_and_rotated(tmp_path):
    normals = [(1, 0, 0)] * 5  # deliberately not the geometric normal
    surface = load_mesh(_author_usd(tmp_path / "n.usda", normals=normals))
    np.testing.assert_allclose(surface.normals, np.tile([0.0, 1.0, 0.0], (5, 1)), atol=1e-12)


def test_usd_face_varying_normals_ignored(tmp_path):
    normals = [(1, 0, 0)] * 9
    surface = load_mesh(
        _author_usd(tmp_path / "fv.usda", normals=normals, interpolation="faceVarying")
    )
    np.testing.assert_allclose(surface.normals, np.tile([0.0, 0.0, 1.0], (5, 1)), atol=1e-12)


def test_usd_instances_orientation_purpose_holes(tmp_path):
    from pxr import Gf, Sdf, Usd, UsdGeom

    path = tmp_path / "scene.usda"
    stage = Usd.Stage.CreateNew(str(path))
    proto = UsdGeom.Mesh.Define(stage, "/Proto/M")
    proto.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)])
    proto.CreateFaceVertexCountsAttr([4])
    proto.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    proto.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)  # front face is -z
    stage.GetPrimAtPath("/Proto").SetSpecifier(Sdf.SpecifierClass)
    for i in range(2):
        xform = UsdGeom.Xform.Define(stage, f"/I{i}")
        xform.AddTranslateOp().Set(Gf.Vec3d(5.0 * i, 0.0, 0.0))
        xform.GetPrim().GetReferences().AddInternalReference("/Proto")
        xform.GetPrim().SetInstanceable(True)
    guide = UsdGeom.Mesh.Define(stage, "/Guide")
    guide.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    guide.CreateFaceVertexCountsAttr([3])
    guide.CreateFaceVertexIndicesAttr([0, 1, 2])
    guide.CreatePurposeAttr(UsdGeom.Tokens.guide)
    holed = UsdGeom.Mesh.Define(stage, "/Holed")
    holed.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)])
    holed.CreateFaceVertexCountsAttr([3, 3])
    holed.CreateFaceVertexIndicesAttr([0, 1, 2, 1, 3, 2])
    holed.CreateHoleIndicesAttr([0])
    stage.GetRootLayer().Save()

    surface = load_mesh(path)
    assert [(p.prim_path, p.vertex_start, p.face_start) for p in surface.parts] == [
        ("/I0/M", 0, 0),
        ("/I1/M", 4, 2),
        ("/Holed", 8, 4),
    ]
    np.testing.assert_array_equal(surface.positions[4], [5.0, 0.0, 0.0])
    np.testing.assert_allclose(surface.normals[:8], np.tile([0.0, 0.0, -1.0], (8, 1)), atol=1e-15)
    np.testing.assert_array_equal(surface.parts[0].face_vertex_indices, [3, 2, 1, 0])
    np.testing.assert_array_equal(surface.faces[4:], [[9, 11, 10]])  # the hole is not traced
    np.testing.assert_array_equal(surface.parts[2].face_vertex_counts, [3, 3])


def test_usd_bad_topology(tmp_path):
    from pxr import Usd, UsdGeom

    path = tmp_path / "bad.usda"
    stage = Usd.Stage.CreateNew(str(path))
    mesh = UsdGeom.Mesh.Define(stage, "/M")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([3, 3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2])
    stage.GetRootLayer().Save()
    with pytest.raises(
        InputError, match=r"^bad.usda: /M: faceVertexCounts sum to 6 but faceVertexIndices has 3"
    ):
        load_mesh(path)


# -- bad inputs --------------------------------------------------------------------------


def _garbage(path):
    path.write_bytes(np.random.default_rng(1).integers(0, 256, 300, dtype=np.uint8).tobytes())
    return path


def _truncated_ply(path):
    write_ply(path, POSITIONS, FACES)
    data = path.read_bytes()
    path.write_bytes(data[:-7])
    return path


NAN_POSITIONS = POSITIONS.copy()
NAN_POSITIONS[2, 1] = np.nan


BAD_INPUTS = {
    "missing.ply": (lambda p: p, "file not found"),
    "folder.ply": (lambda p: (p.mkdir(), p)[1], "is a directory"),
    "mesh.xyz": (lambda p: (p.write_text("1 2 3\n"), p)[1], "unsupported input suffix '.xyz'"),
    "garbage.ply": (_garbage, "cannot read as PLY"),
    "garbage.obj": (_garbage, "cannot read as OBJ"),
    "garbage.stl": (_garbage, "cannot read as STL"),
    "garbage.glb": (_garbage, "cannot read as glTF"),
    "garbage.usda": (_garbage, "cannot read as USD"),
    "nomesh.usda": (
        lambda p: (p.write_text('#usda 1.0\ndef Xform "A" {}\n'), p)[1],
        "no visible UsdGeom.Mesh",
    ),
    "truncated.ply": (_truncated_ply, "cannot read as PLY"),
    "empty.ply": (
        lambda p: write_ply(p, np.zeros((0, 3)), np.zeros((0, 3), int)),
        "mesh is empty (no vertices)",
    ),
    "empty.obj": (lambda p: (p.write_text("# nothing\n"), p)[1], "mesh is empty (no vertices)"),
    "nan.ply": (
        lambda p: write_ply(p, NAN_POSITIONS, FACES),
        "1 vertices have NaN or inf coordinates (first: vertex 2)",
    ),
    "nan.obj": (
        lambda p: write_obj(p, NAN_POSITIONS, FACES),
        "1 vertices have NaN or inf coordinates (first: vertex 2)",
    ),
    "range.ply": (
        lambda p: write_ply(p, POSITIONS, [[0, 1, 2], [0, 1, 8]]),
        "1 faces reference vertex 8 but the mesh has 8 vertices",
    ),
    "range.obj": (
        lambda p: write_obj(p, POSITIONS, [[0, 1, 2], [0, 1, 8]]),
        "1 faces reference vertex 8 but the mesh has 8 vertices",
    ),
    "range.off": (lambda p: write_off(p, POSITIONS, [[0, 1, 2], [0, 1, 8]]), "cannot read as OFF"),
    "nofaces.ply": (
        lambda p: write_ply(p, POSITIONS, np.zeros((0, 3), int)),
        "mesh has 8 vertices but no faces",
    ),
    "nofaces.obj": (lambda p: write_obj(p, POSITIONS, []), "mesh has 8 vertices but no faces"),
    "badnumber.obj": (lambda p: (p.write_text("v 0 0 x\n"), p)[1], "cannot read as OBJ: line 1"),
    "badnormal.obj": (
        lambda p: (p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//2\n"), p)[1],
        "face corners reference normal 2",
    ),
    "zeroindex.obj": (
        lambda p: (p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n"), p)[1],
        "cannot read as OBJ: line 4 ('f 0 1 2'): OBJ indices start at 1, got 0",
    ),
    "binary.obj": (
        lambda p: (p.write_bytes(b"v 0 0 0\x00\n"), p)[1],
        "cannot read as OBJ: binary data, not a text file",
    ),
    "garbage.off": (_garbage, "cannot read as OFF"),
    "noheader.off": (
        lambda p: (p.write_text("3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"), p)[1],
        "cannot read as OFF: missing 'OFF' header",
    ),
    "short.stl": (
        lambda p: (p.write_bytes(b"\x00" * 80 + np.uint32(2).tobytes() + b"\x00" * 50), p)[1],
        "cannot read as STL: neither binary (size does not match the triangle count) nor text",
    ),
    # trimesh reports unparsable glTF JSON as a missing "model.gltf"
    "garbage.gltf": (lambda p: (p.write_text("{not json"), p)[1], "cannot read file"),
    "garbage.usdc": (_garbage, "cannot read as USD"),
    "noz.ply": (
        lambda p: (
            p.write_text(
                "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                "end_header\n0 0\n"
            ),
            p,
        )[1],
        "cannot read as PLY: vertex element lacks property 'z'",
    ),
    "floatindex.ply": (
        lambda p: (
            p.write_text(
                "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                "property float z\nelement face 1\nproperty list uchar float vertex_indices\n"
                "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 1.5\n"
            ),
            p,
        )[1],
        "cannot read as PLY: face 'vertex_indices' holds non-integer indices",
    ),
    "badheader.ply": (
        lambda p: (p.write_text("ply\nformat ascii 1.0\nelement vertex 1\nend_header\n"), p)[1],
        "cannot read as PLY: vertex element lacks property 'x'",
    ),
}


@pytest.mark.parametrize("name", sorted(BAD_INPUTS))
def test_bad_input_one_line_error(tmp_path, name):
    make, expected = BAD_INPUTS[name]
    path = make(tmp_path / name)
    with pytest.raises(InputError) as info:
        load_mesh(path)
    message = str(info.value)
    assert message.startswith(f"{name}: "), message
    assert expected in message
    assert "\n" not in message and "\r" not in message
    assert info.value.path == tmp_path / name
