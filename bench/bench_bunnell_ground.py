"""The disk method's reflecting ground (``--ground`` with bounces) against the reference.

    cd bench && PYTHONPATH=..:. python bench_bunnell_ground.py [--grids 81:16:3.5,81:256:7.5]

A sphere of radius 0.5 (2,562 vertices) resting on the plane z = 0, under a distant, a
point and a dome light in turn; the reference (``--method embree``, the same plane, 512
samples and 8,192 paths) against the disk method with the plane only occluding and with
each ground grid ``points:reach:growth`` (``light.GROUND_POINTS``, ``GROUND_REACH``,
``GROUND_GROWTH``); relative RMSE of the irradiance and of its indirect part, the mean
indirect over the reference's, and the seconds of the disk method. Then a small vertical
plate at height 0.5 under a distant light against the closed form rho E_perp (l.up) / 2.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from bench_light import rel_rmse

from aobake.ground import ALBEDO, Ground
from aobake.mesh import surface_from_arrays
from aobake.methods.bunnell import light as disk
from aobake.methods.embree.light import irradiance
from aobake.shading import Light, default_shading
from aobake.testing.scenes import sphere


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grids", default=f"81:16:3.5,81:64:6,{disk.GROUND_POINTS}:{disk.GROUND_REACH:g}:{disk.GROUND_GROWTH:g}")
    args = parser.parse_args()
    grids = [tuple(float(x) for x in g.split(":")) for g in args.grids.split(",")]
    ball = sphere(0.5, 4)
    ball = surface_from_arrays(ball.positions + np.array([0.0, 0.0, 0.5]), ball.faces)
    ground = Ground(2, 0.0)
    lights = (Light.make("distant", "sun", (3.0,) * 3, direction=(0.3, 0.2, 1.0)),
              Light.make("point", "lamp", (10.0,) * 3, position=(1.0, 0.5, 2.0)),
              Light.make("dome", "sky", (1.0, 1.0, 1.0)))  # fmt: skip
    print(f"a sphere on the plane, {ball.n_vertices} vertices; reference 512 samples, 8,192 paths")
    for light in lights:
        shading = default_shading(ball.n_vertices, ball.n_faces, [light])
        ref = irradiance(ball, shading, n_samples=512, n_indirect=8192, seed=3, ground=ground)
        occluding = disk.prepare_light(ball, shading, ground=ground, ground_reflects=False).light()
        print(f"{light.kind}: the plane only occluding: rel. RMSE {rel_rmse(occluding.irradiance, ref.irradiance):.4f}")
        for points, reach, growth in grids:
            disk.GROUND_POINTS, disk.GROUND_REACH, disk.GROUND_GROWTH = int(points), reach, growth
            t = time.perf_counter()
            r = disk.disk_light(ball, shading, ground=ground)
            dt = time.perf_counter() - t
            print(f"  grid {int(points)}:{reach:g}:{growth:g}: rel. RMSE {rel_rmse(r.irradiance, ref.irradiance):.4f} "
                  f"(indirect {rel_rmse(r.indirect, ref.indirect):.4f}, mean {r.indirect.sum() / ref.indirect.sum():.3f}); "
                  f"{dt:.2f} s")  # fmt: skip
    h, a = 0.5, 0.01
    plate = np.array([[0, -a, h - a], [0, a, h - a], [0, a, h + a], [0, -a, h + a]], dtype=float)
    s = surface_from_arrays(plate, np.array([[0, 2, 1], [0, 3, 2]]))
    sun = Light.make("distant", "sun", (1.0, 1.0, 1.0), direction=(0.3, 0.0, 1.0))
    want = ALBEDO * (1.0 / math.hypot(0.3, 1.0)) / 2
    for points, reach, growth in grids:
        disk.GROUND_POINTS, disk.GROUND_REACH, disk.GROUND_GROWTH = int(points), reach, growth
        r = disk.disk_light(s, default_shading(4, 2, [sun]), ground=ground)
        print(f"plate at 0.5, grid {int(points)}:{reach:g}:{growth:g}: indirect / closed form {r.indirect[:, 0].mean() / want:.4f}")


if __name__ == "__main__":
    main()
