"""What reading a scene's lights costs a bake of a scene without any (issue 15's "same
time"): `lighting.prepare` (read lights and materials, plan) against loading the mesh,
on a ~330k-vertex PLY (with vertex colours) and a USD of 32 meshes with materials and
displayColor. Prints the ratio prepare / load, measured in one run.

    python bench/bench_unlit.py [--subdivisions 7]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def _sphere(subdivisions: int):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    return np.asarray(m.vertices), np.asarray(m.faces)


def _ply(path: Path, positions, faces) -> None:
    from aobake.io.ply import write_ply

    write_ply(path, positions, faces, np.full(len(positions), 0.5), color=True)


def _usd(path: Path, positions, faces, copies: int) -> None:
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Xform.Define(stage, "/World")
    material = UsdShade.Material.Define(stage, "/World/Looks/grey")
    shader = UsdShade.Shader.Define(stage, "/World/Looks/grey/surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.5, 0.5, 0.5))
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    per = len(positions)
    for k in range(copies):
        mesh = UsdGeom.Mesh.Define(stage, f"/World/m{k}")
        mesh.CreatePointsAttr((positions + [3.0 * k, 0, 0]).astype(np.float32))
        mesh.CreateFaceVertexCountsAttr(np.full(len(faces), 3, dtype=np.int32))
        mesh.CreateFaceVertexIndicesAttr(faces.astype(np.int32).ravel())
        mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex).Set(np.full((per, 3), 0.3, dtype=np.float32))
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    stage.GetRootLayer().Save()


def _time(fn, repeats: int = 3) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subdivisions", type=int, default=7)
    args = parser.parse_args()
    from aobake import lighting
    from aobake.io import load_mesh

    positions, faces = _sphere(args.subdivisions)
    with tempfile.TemporaryDirectory() as tmp:
        ply, usd = Path(tmp) / "unlit.ply", Path(tmp) / "unlit.usdc"
        _ply(ply, positions, faces)
        small_p, small_f = _sphere(max(args.subdivisions - 2, 1))
        _usd(usd, small_p, small_f, 32)
        for path in (ply, usd):
            surface = load_mesh(path)
            load = _time(lambda p=path: load_mesh(p))
            prep = _time(lambda p=path, s=surface: lighting.prepare(p, s, "embree", {}))
            job = lighting.prepare(path, surface, "embree", {})
            print(
                f"{path.suffix}: {surface.n_vertices} vertices, load {load:.3f} s, reading lights and planning "
                f"{prep:.3f} s ({prep / load:.2f} of the load); job: {job}"
            )


if __name__ == "__main__":
    main()
