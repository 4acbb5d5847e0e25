"""Do two checkouts give the same results? Bakes fixed meshes with every method at fixed
options and seeds, for a restructuring that must change no result (issue 13).

    python bench/same_results.py cases CASES.npz            # meshes, from this checkout
    PYTHONPATH=<checkout> python bench/same_results.py run CASES.npz OUT.npz   # twice: the
                                                            # second run loads cached kernels
    python bench/same_results.py compare A.npz B.npz        # bit for bit
    PYTHONPATH=<checkout> python bench/same_results.py lights OUT.npz   # the light cases alone

The meshes are the hard cases of aobake.testing plus a jittered sphere-on-ground scene
with shuffled vertices; a checkout that predates aobake.testing bakes them from the file.
The light transport (``aobake.methods.embree.light``) is run on the bundled Cornell-like
box, as it is and with every kind of light, emitting faces and a ground plane added
(:data:`LIGHT_CONFIGS`), on one and two threads.
"""

from __future__ import annotations

import sys

import numpy as np

CONFIGS = {
    "embree": ("embree", {"n_rays": 64, "seed": 3}),
    "embree-uniform": ("embree", {"n_rays": 32, "measure": "uniform", "max_distance": 0.3, "seed": 1}),
    "embree-adaptive": ("embree", {"n_rays": 128, "tolerance": 0.05, "seed": 2}),
    "bunnell": ("bunnell", {}),
    "bunnell-passes2": ("bunnell", {"passes": 2}),
    "bunnell-plain": ("bunnell", {"theta": 4.0, "directional": False, "near": 0.0}),
    "bunnell-uniform": ("bunnell", {"measure": "uniform", "max_distance": 0.5, "passes": 3}),
}


LIGHT_CONFIGS = {
    "direct": ("box", {"n_samples": 16, "bounces": 0}),
    "bounce1": ("box", {"n_samples": 8, "n_indirect": 16, "bounces": 1}),
    "bounce2-adaptive": ("box", {"n_samples": 64, "n_indirect": 32, "bounces": 2, "tolerance": 0.05, "seed": 7}),
    "all-kinds": ("all", {"n_samples": 8, "n_indirect": 8, "bounces": 2, "seed": 3}),
    "all-kinds-ground": ("all", {"n_samples": 8, "n_indirect": 8, "bounces": 1, "ground": True, "max_distance": 3.0}),
}


def _light_scenes():
    """The box with its lights and materials; the box with a light of every kind (one of
    them without shadows, one with a range), two emitting faces and a dome added."""
    from pathlib import Path

    from aobake.io import load_mesh
    from aobake.io.lights import read_shading
    from aobake.shading import Light, Shading

    path = Path(__file__).resolve().parent.parent / "data" / "cornell_box.usda"
    surface = load_mesh(path)
    shading = read_shading(path, surface)
    extra = (
        Light.make("point", "p", (0.3, 0.2, 0.1), position=(0.5, 0.8, 0.5)),
        Light.make("point", "ranged", (0.2, 0.2, 0.2), position=(0.2, 0.3, 0.7), range=0.6),
        Light.make("spot", "s", (0.5, 0.5, 0.4), position=(0.8, 0.9, 0.6), direction=(0, -1, 0),
                   cone_inner=0.3, cone_outer=0.6),
        Light.make("sphere", "sph", (0.4, 0.3, 0.3), position=(0.3, 0.7, 0.4), radius=0.05),
        Light.make("disk", "d", (0.6, 0.6, 0.6), position=(0.5, 0.95, 0.3), radius=0.1, normal=(0, -1, 0)),
        Light.make("distant", "sun", (0.5, 0.5, 0.5), direction=(0.2, 1.0, 0.4), angle=0.05),
        Light.make("distant", "sharp", (0.1, 0.1, 0.2), direction=(0.0, 0.3, 1.0), shadow=False),
        Light.make("dome", "sky", (0.05, 0.06, 0.08)),
    )
    emission = np.array(shading.face_emission, dtype=float)
    emission[[3, 40]] = (0.5, 0.4, 0.3)
    every = Shading(shading.lights + extra, shading.face_albedo, emission, shading.vertex_albedo,
                    shading.vertex_emission)  # fmt: skip
    return surface, {"box": shading, "all": every}


def _lights(res: dict) -> None:
    from aobake.ground import Ground
    from aobake.methods.embree.light import irradiance

    surface, shadings = _light_scenes()
    floor = Ground(1, float(surface.positions[:, 1].min()) - 0.01)
    for label, (scene, opts) in LIGHT_CONFIGS.items():
        opts = dict(opts)
        ground = floor if opts.pop("ground", False) else None
        for threads in (1, 2):
            r = irradiance(surface, shadings[scene], threads=threads, ground=ground, **opts)
            for name in ("direct", "indirect", "error", "samples"):
                res[f"light-{label}-t{threads}/{name}"] = getattr(r, name)
            res[f"light-{label}-t{threads}/rays"] = np.array([r.n_shadow_rays, r.n_bounce_rays])


def cases(path: str) -> None:
    from aobake.testing import hard_cases, scenes

    out = {}
    for name, make in hard_cases.CASES.items():
        s = make()
        out[f"{name}__p"], out[f"{name}__f"], out[f"{name}__n"] = s.positions, s.faces, s.normals
    rng = np.random.default_rng(5)
    s, _ = scenes.sphere_on_ground(0.5, 3, gap=0.0, cells=20)
    p = s.positions + rng.normal(scale=1e-3, size=s.positions.shape)
    perm = rng.permutation(len(p))
    inverse = np.empty_like(perm)
    inverse[perm] = np.arange(len(p))
    out["jittered_shuffled__p"], out["jittered_shuffled__f"] = p[perm], inverse[s.faces]
    out["jittered_shuffled__n"] = np.zeros((0, 3))
    np.savez(path, **out)


def run(cases_path: str, path: str) -> None:
    import aobake
    from aobake.mesh import surface_from_arrays

    z = np.load(cases_path)
    res = {}
    for name in sorted({k.split("__")[0] for k in z.files}):
        n = z[f"{name}__n"]
        s = surface_from_arrays(z[f"{name}__p"], z[f"{name}__f"], n if len(n) else None)
        for label, (method, opts) in CONFIGS.items():
            res[f"{name}/{label}"] = np.asarray(aobake.bake(s, method, **opts))
    try:
        from aobake.methods.fields import field_ao, fit_field

        rays = "n_rays"
    except ImportError:  # a checkout from before the fields' room
        from aobake.field import field_ao, fit_field

        rays = "rays"
    occluder = surface_from_arrays(z["needles_and_slivers__p"], z["needles_and_slivers__f"])
    receiver = surface_from_arrays(z["jittered_shuffled__p"], z["jittered_shuffled__f"])
    fits = {
        "raster": {"resolution": 6},
        "embree": {"resolution": 6, "sampler": "embree", rays: 64, "seed": 4},
        "table": {"resolution": 6, "model": "table", "prefilter": 2},
    }
    for label, kw in fits.items():
        field = fit_field(occluder, **kw)
        points = receiver.positions * 0.3 + np.array([0.0, 0.0, 0.6])
        res[f"field/{label}"] = field_ao(field, points, receiver.normals)
    _lights(res)
    np.savez(path, **{k.replace("/", "__"): v for k, v in res.items()})


def compare(a_path: str, b_path: str) -> int:
    a, b = np.load(a_path), np.load(b_path)
    if sorted(a.files) != sorted(b.files):
        print("different cases")
        return 1
    differ = [k for k in a.files if not np.array_equal(a[k], b[k])]
    print(f"{len(a.files)} results, {len(a.files) - len(differ)} bit-identical, {len(differ)} differ")
    for k in differ:
        print(f"  {k.replace('__', '/')}: max |diff| {np.abs(a[k] - b[k]).max():.3g}")
    return 1 if differ else 0


if __name__ == "__main__":
    verb, *args = sys.argv[1:]
    if verb == "cases":
        cases(*args)
    elif verb == "run":
        run(*args)
    elif verb == "lights":
        out = {}
        _lights(out)
        np.savez(args[0], **{k.replace("/", "__"): v for k, v in out.items()})
    else:
        sys.exit(compare(*args))
