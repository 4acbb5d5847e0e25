"""Regenerate the meshes in data/ (see data/README.md for provenance and licences).

    python data/make_data.py                      # all files; fetches the bunny with npm
    python data/make_data.py --bunny bunny-1.0.1.tgz   # bunny from a downloaded package
    python data/make_data.py --skip-bunny         # procedural scenes only (numpy only)

The bunny comes from the npm package ``bunny`` 1.0.1 (Mikola Lysenko), fetched with::

    npm pack bunny@1.0.1        # -> bunny-1.0.1.tgz, sha1 86383da45ab7a99571a5a572b7be0e3564815f9e

whose ``index.js`` holds ``exports.positions`` and ``exports.cells`` as JSON arrays; the
vertex and face order are kept. The procedural scenes need only numpy and are
deterministic. Every file is a binary little-endian PLY with float32 ``x y z`` and int32
triangle lists, so `make bake` never needs npm.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import re
import shutil
import subprocess
import tarfile
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
BUNNY_SPEC = "bunny@1.0.1"
BUNNY_SHA1 = "86383da45ab7a99571a5a572b7be0e3564815f9e"

log = logging.getLogger("make_data")


def write_ply(path: Path, positions: np.ndarray, faces: np.ndarray, comments: list[str]) -> None:
    """Binary little-endian PLY: float32 x y z, uchar-counted int32 triangle lists."""
    positions = np.asarray(positions, dtype="<f4")
    faces = np.asarray(faces, dtype="<i4")
    assert positions.ndim == 2 and positions.shape[1] == 3 and np.isfinite(positions).all()
    assert faces.ndim == 2 and faces.shape[1] == 3
    assert faces.min() >= 0 and faces.max() < len(positions)
    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {line}" for line in comments]
    header += [
        f"element vertex {len(positions)}",
        "property float x",
        "property float y",
        "property float z",
        f"element face {len(faces)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    records = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    records["n"] = 3
    records["v"] = faces
    path.write_bytes(
        ("\n".join(header) + "\n").encode("ascii") + positions.tobytes() + records.tobytes()
    )
    log.info(
        "%s: %d vertices, %d faces, %d bytes",
        path.name,
        len(positions),
        len(faces),
        path.stat().st_size,
    )


# -- bunny ----------------------------------------------------------------------------


def fetch_bunny(workdir: Path) -> Path:
    """``npm pack bunny@1.0.1`` into ``workdir``; returns the tarball."""
    npm = shutil.which("npm")
    if npm is None:
        raise SystemExit("npm not found: pass --bunny bunny-1.0.1.tgz or --skip-bunny")
    subprocess.run(
        [npm, "pack", BUNNY_SPEC, "--silent"], cwd=workdir, check=True, capture_output=True
    )
    return workdir / "bunny-1.0.1.tgz"


def read_bunny(tarball: Path) -> tuple[np.ndarray, np.ndarray]:
    """Positions (n, 3) and cells (m, 3) from the package's index.js, in package order."""
    digest = hashlib.sha1(tarball.read_bytes()).hexdigest()
    if digest != BUNNY_SHA1:
        raise SystemExit(f"{tarball.name}: sha1 {digest}, expected {BUNNY_SHA1}")
    with tarfile.open(tarball) as archive:
        text = archive.extractfile("package/index.js").read().decode("utf-8")
    arrays = {}
    for key in ("positions", "cells"):
        match = re.search(rf"exports\.{key}\s*=\s*(\[\s*\[.*?\]\s*\])", text, re.S)
        if match is None:
            raise SystemExit(f"index.js: no exports.{key}")
        arrays[key] = np.array(json.loads(match.group(1)))
    return arrays["positions"].astype(np.float64), arrays["cells"].astype(np.int64)


def make_bunny(tarball: Path | None) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        source = tarball if tarball is not None else fetch_bunny(Path(tmp))
        positions, cells = read_bunny(source)
    write_ply(
        HERE / "bunny.ply",
        positions,
        cells,
        [
            "Stanford bunny (Stanford 3D Scanning Repository), reduced resolution,",
            "from npm package bunny 1.0.1 by Mikola Lysenko (license field: Public Domain).",
            "Vertex and face order as in the package. Up axis +Y. Units arbitrary.",
        ],
    )


# -- procedural scenes ------------------------------------------------------------------


def patch(origin, u, v, nu: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """A planar grid of nu x nv quads, two triangles each, counter-clockwise about u x v."""
    origin, u, v = (np.asarray(a, dtype=np.float64) for a in (origin, u, v))
    i, j = np.meshgrid(np.arange(nu + 1), np.arange(nv + 1), indexing="ij")
    positions = origin + (i.reshape(-1, 1) / nu) * u + (j.reshape(-1, 1) / nv) * v
    index = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
    c, d = index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return positions, faces


def box(lo, hi, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed axis-aligned box, each side an n x n grid with its own (split) vertices."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    dx, dy, dz = (x1 - x0, 0, 0), (0, y1 - y0, 0), (0, 0, z1 - z0)
    sides = [
        ((x0, y0, z0), dy, dx),  # -z
        ((x0, y0, z1), dx, dy),  # +z
        ((x0, y0, z0), dz, dy),  # -x
        ((x1, y0, z0), dy, dz),  # +x
        ((x0, y0, z0), dx, dz),  # -y
        ((x0, y1, z0), dz, dx),  # +y
    ]
    return combine([patch(o, u, v, n, n) for o, u, v in sides])


def combine(meshes) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate (positions, faces) pairs, offsetting the indices."""
    positions, faces, offset = [], [], 0
    for p, f in meshes:
        positions.append(p)
        faces.append(f + offset)
        offset += len(p)
    return np.concatenate(positions), np.concatenate(faces)


def icosphere(subdivisions: int, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Subdivided icosahedron projected to the sphere (midpoints shared, deterministic)."""
    t = (1.0 + 5.0**0.5) / 2.0
    positions = [
        (-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
        (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1),
    ]  # fmt: skip
    faces = [
        (0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
        (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
        (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1),
    ]  # fmt: skip
    points = [np.array(p, dtype=np.float64) / np.linalg.norm(p) for p in positions]
    for _ in range(subdivisions):
        midpoint: dict[tuple[int, int], int] = {}

        def middle(a: int, b: int, midpoint: dict = midpoint) -> int:
            key = (min(a, b), max(a, b))
            if key not in midpoint:
                m = points[a] + points[b]
                points.append(m / np.linalg.norm(m))
                midpoint[key] = len(points) - 1
            return midpoint[key]

        refined = []
        for a, b, c in faces:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            refined += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = refined
    return np.array(points) * radius, np.array(faces, dtype=np.int64)


def rotation_to(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation matrix taking unit vector a to unit vector b (Rodrigues; a != -b)."""
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


def make_sphere_on_ground() -> None:
    """Icosphere (3 subdivisions, radius 0.5) touching a 4 x 4 ground grid at one vertex."""
    sphere, sphere_faces = icosphere(3, 0.5)
    lowest = int(np.argmin(sphere[:, 2]))
    rotation = rotation_to(
        sphere[lowest] / np.linalg.norm(sphere[lowest]), np.array([0.0, 0.0, -1.0])
    )
    sphere = sphere @ rotation.T
    sphere = sphere - sphere[lowest]  # that vertex becomes exactly (0, 0, 0)
    assert np.array_equal(sphere[lowest], [0.0, 0.0, 0.0])
    others = np.delete(sphere[:, 2], lowest)
    assert others.min() > 1e-3, "the contact vertex must be the sphere's unique lowest point"
    ground = patch((-2.0, -2.0, 0.0), (4.0, 0.0, 0.0), (0.0, 4.0, 0.0), 20, 20)
    assert np.array_equal(ground[0][220], [0.0, 0.0, 0.0])  # grid vertex under the contact
    positions, faces = combine([(sphere, sphere_faces), ground])
    write_ply(
        HERE / "sphere_on_ground.ply",
        positions,
        faces,
        [
            "aobake procedural contact scene (CC0): icosphere, 3 subdivisions, radius 0.5,",
            "its lowest vertex at (0, 0, 0) on a 4 x 4 ground grid of 20 x 20 quads at z = 0.",
            "Sphere vertices first, then ground. Up axis +Z.",
        ],
    )


def make_box_stack() -> None:
    """Floor and two walls meeting in a corner, three boxes: on the floor near both walls,
    stacked and turned on top of it, and one a narrow gap from a wall."""
    floor = patch((0.0, 0.0, 0.0), (3.0, 0.0, 0.0), (0.0, 3.0, 0.0), 12, 12)
    wall_x = patch((0.0, 0.0, 0.0), (0.0, 3.0, 0.0), (0.0, 0.0, 1.5), 12, 6)  # faces +x
    wall_y = patch((0.0, 0.0, 0.0), (0.0, 0.0, 1.5), (3.0, 0.0, 0.0), 6, 12)  # faces +y
    base = box((0.25, 0.25, 0.0), (1.25, 1.25, 1.0), 4)
    top_p, top_f = box((-0.25, -0.25, 0.0), (0.25, 0.25, 0.5), 2)
    angle = np.radians(30.0)
    turn = np.array(
        [[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]]
    )
    top_p = top_p @ turn.T + [0.85, 0.8, 1.0]
    side = box((0.05, 1.6, 0.0), (0.65, 2.2, 0.6), 3)  # 0.05 from the x = 0 wall
    positions, faces = combine([floor, wall_x, wall_y, base, (top_p, top_f), side])
    write_ply(
        HERE / "box_stack.ply",
        positions,
        faces,
        [
            "aobake procedural corner scene (CC0): floor and walls x = 0, y = 0 (height 1.5),",
            "a unit box on the floor, a 0.5 box turned 30 degrees on top, a 0.6 box 0.05 from",
            "the x = 0 wall. Closed boxes with split vertices per side. Up axis +Z.",
        ],
    )


#: Diffuse reflectances of the Cornell box (linear RGB, the classic measured values rounded).
CORNELL_COLORS = {
    "white": (0.73, 0.73, 0.73),
    "red": (0.63, 0.065, 0.05),
    "green": (0.14, 0.45, 0.091),
}


def turned_box(lo, hi, degrees: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`box` turned by ``degrees`` about the vertical (+Y) axis through its centre."""
    positions, faces = box(lo, hi, n)
    centre = 0.5 * (np.asarray(lo, dtype=np.float64) + np.asarray(hi, dtype=np.float64))
    a = np.radians(degrees)
    turn = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    return (positions - centre) @ turn.T + centre, faces


def make_cornell_box() -> None:
    """A 1 m Cornell-like box (USD, +Y up, open at z = 1): white floor, ceiling and back
    wall, red left and green right walls, two turned blocks, a square RectLight under the
    ceiling shining down. Needs usd-core (an aobake dependency)."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade

    n = 12
    walls = {
        "floor": (patch((0, 0, 0), (0, 0, 1), (1, 0, 0), n, n), "white"),
        "ceiling": (patch((0, 1, 0), (1, 0, 0), (0, 0, 1), n, n), "white"),
        "back": (patch((0, 0, 0), (1, 0, 0), (0, 1, 0), n, n), "white"),
        "left": (patch((0, 0, 0), (0, 1, 0), (0, 0, 1), n, n), "red"),
        "right": (patch((1, 0, 0), (0, 0, 1), (0, 1, 0), n, n), "green"),
    }
    blocks = {
        "tall": (turned_box((0.53, 0.0, 0.2), (0.83, 0.6, 0.5), 15.0, 3), "white"),
        "short": (turned_box((0.17, 0.0, 0.45), (0.47, 0.3, 0.75), -18.0, 3), "white"),
    }
    path = HERE / "cornell_box.usda"
    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    stage.GetRootLayer().documentation = (
        "aobake procedural Cornell-like box (CC0): 1 m box, +Y up, open at z = 1; white floor, "
        "ceiling and back, red left (x = 0) and green right (x = 1) walls, two blocks; a 0.3 m "
        "RectLight under the ceiling shining down. Regenerate with data/make_data.py."
    )
    UsdGeom.Scope.Define(stage, "/World/Looks")
    looks = {}
    for name, rgb in CORNELL_COLORS.items():
        material = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
        shader = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/surface")
        shader.CreateIdAttr("UsdPreviewSurface")
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*rgb))
        shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(1.0)
        material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        looks[name] = material
    for group, items in (("box", walls), ("blocks", blocks)):
        UsdGeom.Xform.Define(stage, f"/World/{group}")
        for name, ((positions, faces), look) in items.items():
            mesh = UsdGeom.Mesh.Define(stage, f"/World/{group}/{name}")
            mesh.CreatePointsAttr([Gf.Vec3f(*map(float, p)) for p in positions])
            mesh.CreateFaceVertexCountsAttr([3] * len(faces))
            mesh.CreateFaceVertexIndicesAttr([int(i) for i in faces.ravel()])
            mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(looks[look])
    light = UsdLux.RectLight.Define(stage, "/World/light")
    light.CreateWidthAttr(0.3)
    light.CreateHeightAttr(0.3)
    light.CreateIntensityAttr(12.0)
    light.CreateColorAttr(Gf.Vec3f(1.0, 0.88, 0.72))
    xform = UsdGeom.Xformable(light.GetPrim())
    xform.AddTranslateOp().Set(Gf.Vec3d(0.5, 0.995, 0.5))
    xform.AddRotateXYZOp().Set(Gf.Vec3f(-90.0, 0.0, 0.0))  # local -Z (emission) -> world -Y
    path.write_text(stage.GetRootLayer().ExportToString())
    log.info("%s: %d bytes", path.name, path.stat().st_size)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bunny", type=Path, help="bunny-1.0.1.tgz from `npm pack bunny@1.0.1`")
    parser.add_argument("--skip-bunny", action="store_true", help="only the procedural scenes")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if not args.skip_bunny:
        make_bunny(args.bunny)
    make_sphere_on_ground()
    make_box_stack()
    make_cornell_box()


if __name__ == "__main__":
    main()
