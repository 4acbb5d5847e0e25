"""Re-lighting a prepared scene with the disk method (``prepare_light`` / ``LitScene.light``):
each call equals a fresh ``disk_light`` with the same lights, bit for bit, whatever was
lit before; what the lights do not change (the Embree scene, the contact-safe origins,
the trees, a dome's AO, unchanged area lights' passes) is built once."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import aobake.methods.bunnell.light as disk
from aobake.errors import InputError
from aobake.io import load_mesh
from aobake.io.lights import read_shading
from aobake.methods.bunnell import BunnellOptions, prepare_light
from aobake.methods.bunnell.light import disk_light
from aobake.shading import Light

CORNELL = Path(__file__).resolve().parents[1] / "data" / "cornell_box.usda"


@pytest.fixture(scope="module")
def box():
    surface = load_mesh(CORNELL)
    return surface, read_shading(CORNELL, surface)


def _lamp(x, z=1.6, power=3.0):
    return Light.make("point", f"lamp{x}", (power, power, 0.8 * power), position=(x, z, 0.2))


def _same(a, b):
    assert np.array_equal(a.direct, b.direct) and np.array_equal(a.indirect, b.indirect)
    assert (a.n_shadow_rays, a.negative, a.contacts, a.lights) == (b.n_shadow_rays, b.negative, b.contacts, b.lights)


def test_each_relighting_equals_a_fresh_bake(box):
    """The box's own RectLight, then point lights moved about, the RectLight back with a
    lamp, a shadowed dome, the scene's lights again: every call as a fresh bake."""
    surface, shading = box
    options = BunnellOptions(threads=2)
    scene = prepare_light(surface, shading, options)
    rect = shading.lights
    dome = Light.make("dome", "sky", (0.3, 0.4, 0.5))
    sequence = [None, (_lamp(-0.3),), (_lamp(0.3),), (*rect, _lamp(0.0)), (dome,), (_lamp(0.3), dome), None]
    seen = []
    for lights in sequence:
        got = scene.light(lights)
        want = disk_light(surface, shading if lights is None else replace(shading, lights=lights), options)
        _same(got, want)
        assert np.isfinite(got.irradiance).all() and got.irradiance.max() > 0
        seen.append(got.irradiance)
    assert not np.array_equal(seen[1], seen[2])  # the lamp moved: the light did
    assert np.array_equal(seen[0], seen[-1])
    assert seen[1][:, 0].max() > 0 and np.any(seen[1] != seen[2])
    # bounces per call
    _same(scene.light((_lamp(0.1),), bounces=0), disk_light(surface, replace(shading, lights=(_lamp(0.1),)), options, bounces=0))


def test_relighting_builds_once_what_the_lights_do_not_change(box, monkeypatch):
    """Moving a point light under a fixed RectLight: one Embree scene, one search for
    contact-safe origins, one set of trees, one aimed pass for the RectLight; a shadowed
    dome's AO once."""
    surface, shading = box
    counts = {}

    def counted(name, fn):
        def wrapped(*a, **k):
            counts[name] = counts.get(name, 0) + 1
            return fn(*a, **k)

        return wrapped

    monkeypatch.setattr(disk, "tracer_for", counted("tracer", disk.tracer_for))
    monkeypatch.setattr(disk, "contact_origins", counted("origins", disk.contact_origins))
    monkeypatch.setattr(disk, "_aimed", counted("aimed", disk._aimed))
    monkeypatch.setattr(disk._Trees, "__init__", counted("trees", disk._Trees.__init__))
    import aobake.methods.bunnell.estimator as est

    monkeypatch.setattr(est, "bunnell_ao", counted("ao", est.bunnell_ao))
    scene = prepare_light(surface, shading)
    dome = Light.make("dome", "sky", (0.3, 0.4, 0.5))
    for x in (-0.3, 0.0, 0.3):
        scene.light((*shading.lights, _lamp(x), dome))
    assert counts == {"tracer": 1, "origins": 1, "aimed": 1, "trees": 1, "ao": 1}
    moved = replace(shading.lights[0], position=shading.lights[0].position + 0.05)
    scene.light((moved,))
    assert counts["aimed"] == 2  # a moved area light is passed again


def test_relighting_takes_light_strings_and_names_the_file_on_a_bad_one(box):
    surface, shading = box
    scene = prepare_light(surface, shading)
    _same(scene.light(["point:0,1.6,0.2:3"]), scene.light([Light.make("point", "--light 1", (3.0,) * 3, position=(0, 1.6, 0.2))]))
    with pytest.raises(InputError) as err:
        scene.light(["point:0,1.6"])
    assert "cornell_box.usda" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(TypeError, match="light 1"):
        scene.light([(0.0, 1.0, 0.0)])
