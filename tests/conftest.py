"""Shared fixtures and hypothesis profiles."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from click.testing import CliRunner
from hypothesis import settings

settings.register_profile("ci", deadline=None, derandomize=True, print_blob=True)
settings.register_profile("dev", deadline=None)
settings.load_profile("ci" if os.environ.get("CI") else "dev")


@pytest.fixture
def runner() -> CliRunner:
    """A click runner for the CLI (stdout and stderr kept apart)."""
    return CliRunner()


@pytest.fixture
def scene_ply(tmp_path) -> Path:
    """A small sphere resting on a floor (contacts, a crevice, open ground) as PLY;
    modules that need a larger scene define their own."""
    import trimesh

    from aobake.testing import scenes

    s, _ = scenes.sphere_on_ground(0.5, 1, gap=0.0, cells=3)
    path = tmp_path / "scene.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(path)
    return path
