"""Library entry points: bake / bake_file, progress reporting, summaries."""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh

import aobake
from aobake.errors import FormatError, InputError
from aobake.io import read_bake
from aobake.progress import NullProgress, StderrProgress, make_progress
from aobake.testing import scenes


def test_bake_accepts_trimesh_surface_and_path(tmp_path):
    box = trimesh.creation.box()
    np.testing.assert_array_equal(aobake.bake(box, n_rays=8), 1.0)
    s, _ = scenes.sphere_on_ground(0.5, 2, cells=4)
    a = aobake.bake(s, n_rays=16, seed=3)
    path = tmp_path / "s.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(path)
    b = aobake.bake(path, n_rays=16, seed=3)
    assert a.shape == b.shape == (s.n_vertices,)
    # the file carries float32 positions and recomputed normals: nearly the same bake
    assert np.mean(np.abs(a - b)) < 0.02


def test_bake_file_roundtrip_and_report(tmp_path):
    s, _ = scenes.sphere_on_ground(0.5, 2, cells=4)
    src = tmp_path / "s.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(src)
    out = tmp_path / "s_ao.usdc"
    report = aobake.bake_file(src, out, n_rays=16, seed=2)
    np.testing.assert_array_equal(
        read_bake(out).astype(np.float32), aobake.bake(src, n_rays=16, seed=2).astype(np.float32)
    )
    assert report.n_vertices == s.n_vertices and report.n_rays == 16 * s.n_vertices
    line = report.summary()
    assert line.startswith("s.ply: ") and "M rays/s" in line and "\n" not in line


def test_bake_file_checks_output_first(tmp_path):
    with pytest.raises(FormatError):
        aobake.bake_file(tmp_path / "missing.ply", tmp_path / "out.txt")
    with pytest.raises(InputError, match=r"^missing\.ply: "):
        aobake.bake_file(tmp_path / "missing.ply", tmp_path / "out.ply")


def test_unknown_method():
    with pytest.raises(ValueError, match="unknown method"):
        aobake.bake(trimesh.creation.box(), method="magic")


def test_progress_bar_only_on_a_terminal():
    class Tty(io.StringIO):
        def isatty(self):
            return True

    assert isinstance(make_progress(False, io.StringIO()), NullProgress)
    assert isinstance(make_progress(True, Tty()), NullProgress)
    stream = Tty()
    bar = make_progress(False, stream)
    assert isinstance(bar, StderrProgress)
    s, _ = scenes.sphere_on_ground(0.5, 2, cells=4)
    aobake.bake(s, n_rays=8, progress=bar)
    text = stream.getvalue()
    assert "embree [" in text and "100.0%" in text and text.endswith("\n")


def test_several_outputs_from_one_bake(tmp_path):
    s, _ = scenes.sphere_on_ground(0.5, 2, cells=4)
    src = tmp_path / "s.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(src)
    outs = [tmp_path / "a.ply", tmp_path / "a.usda"]
    report = aobake.bake_file(src, outs, n_rays=16)
    np.testing.assert_array_equal(read_bake(outs[0]), read_bake(outs[1]))
    assert report.n_rays == 16 * s.n_vertices  # baked once


def test_failure_in_second_output_leaves_neither(tmp_path, monkeypatch):
    import aobake.io

    s, _ = scenes.sphere_on_ground(0.5, 2, cells=4)
    src = tmp_path / "s.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(src)
    real = aobake.io.write_bake
    calls = []

    def flaky(path, *args, **kwargs):
        calls.append(path)
        if len(calls) == 2:
            raise OSError("disk full")
        return real(path, *args, **kwargs)

    monkeypatch.setattr(aobake.io, "write_bake", flaky)
    with pytest.raises(aobake.errors.OutputError, match=r"^a\.usda: cannot write \(disk full\)$"):
        aobake.bake_file(src, [tmp_path / "a.ply", tmp_path / "a.usda"], n_rays=8)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.ply"]


@pytest.mark.parametrize("light", [False, True])
def test_bake_file_builds_the_embree_scene_during_the_normals(tmp_path, monkeypatch, light):
    # An embree bake starts its Embree scene (tracing.start_scene) once the mesh is read,
    # before the normals, and traces that very scene (its AO and, lit, its light): the
    # files are the bytes of a bake that builds it after them (EARLY_SCENE_MAX_VERTICES 0)
    import aobake.constants
    import aobake.mesh
    import aobake.tracing
    from aobake.methods.embree import estimator
    from aobake.methods.embree import light as light_module

    s, _ = scenes.sphere_on_ground(0.5, 2, cells=4)
    src = tmp_path / "s.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(src)
    events, traced = [], []
    start, normals, tracer_for = aobake.tracing.start_scene, aobake.mesh.angle_weighted_normals, estimator.tracer_for
    monkeypatch.setattr(aobake.tracing, "start_scene", lambda p, f: events.append(start(p, f)) or events[-1])
    monkeypatch.setattr(aobake.mesh, "angle_weighted_normals", lambda p, f: events.append("normals") or normals(p, f))
    for module in (estimator, light_module):
        monkeypatch.setattr(module, "tracer_for", lambda *a, **k: traced.append(tracer_for(*a, **k)) or traced[-1])
    extra = {"lights": ["distant:0,-1,0:2"]} if light else {}
    aobake.bake_file(src, tmp_path / "early.ply", n_rays=8, seed=1, **extra)
    assert len(events) == 2 and events[1] == "normals" and traced == [events[0][2]] * (2 if light else 1)
    assert events[0][0] is not None and traced[0]._building is None and traced[0]._embree is not None
    monkeypatch.setattr(aobake.constants, "EARLY_SCENE_MAX_VERTICES", 0)
    aobake.bake_file(src, tmp_path / "late.ply", n_rays=8, seed=1, **extra)
    assert len(events) == 3 and (tmp_path / "early.ply").read_bytes() == (tmp_path / "late.ply").read_bytes()
    aobake.bake_file(src, tmp_path / "bunnell.ply", method="bunnell")
    assert len(events) == 4  # no Embree scene for a method that traces none
