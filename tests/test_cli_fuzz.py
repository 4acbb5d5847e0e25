"""Option and output-name fuzzing of `aobake bake` (hypothesis; a tiny mesh, few rays).

The model: an option the chosen method does not take, or a value outside its range, is
a usage error (exit 2) whatever else is given; otherwise the bake succeeds and writes
finite ``ao`` in [0, 1] for every vertex. Every failure is one ``Error:`` line, with no
traceback and no file left behind.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from aobake.cli import _method_fields, main
from aobake.io import BAKE_SUFFIXES, read_bake
from aobake.methods import METHODS
from aobake.options import flag
from aobake.testing import scenes

FIELDS = _method_fields()
FUZZ = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> tuple[Path, int]:
    s, _ = scenes.sphere_on_ground(0.5, 1, gap=0.0, cells=2)
    path = tmp_path_factory.mktemp("fuzz") / "scene.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(path)
    return path, s.n_vertices


def _valid(spec) -> st.SearchStrategy:
    """Values the option takes, kept small so a bake stays cheap."""
    if spec.kind is bool:
        return st.booleans()
    if spec.choices is not None:
        return st.sampled_from(spec.choices)
    low = 0.0 if spec.low is None else float(spec.low)
    high = low + (4 if spec.kind is int else 2.0)
    if spec.high is not None:
        high = min(high, float(spec.high))
    if spec.kind is int:
        return st.integers(int(low) + int(spec.low_open), int(high))
    return st.floats(low, high, exclude_min=spec.low_open, allow_nan=False).map(lambda v: round(v, 6)).filter(
        lambda v: v > low if spec.low_open else v >= low
    )


def _invalid(spec) -> st.SearchStrategy:
    """Values the option refuses: below its range, NaN or infinity, not a number, not a choice."""
    if spec.kind is bool:
        return st.nothing()
    if spec.choices is not None:
        return st.sampled_from(["bogus", ""])
    bad = ["abc", "1e", ""]
    if spec.kind is float:
        bad += ["nan", "inf", "-inf"]
    if spec.kind is int:
        bad += ["1.5"]
    if spec.low is not None:
        bad.append(str(spec.low if spec.low_open else spec.low - 1))
    return st.sampled_from(bad)


@st.composite
def option_sets(draw):
    method = draw(st.sampled_from(METHODS))
    names = draw(st.lists(st.sampled_from(sorted(FIELDS)), unique=True, max_size=4))
    args, expect_usage = [], False
    for name in names:
        spec, defaults = FIELDS[name]
        if name == "threads":  # more threads than cores is the input side's to clamp
            value = draw(st.integers(1, 2))
            bad = False
        else:
            bad = spec.kind is not bool and draw(st.booleans()) and draw(st.integers(0, 3)) == 0
            value = draw(_invalid(spec) if bad else _valid(spec))
        expect_usage |= bad or method not in defaults
        if spec.kind is bool:
            args.append(flag(name, spec) if value else f"--no-{flag(name, spec)[2:]}")
        else:
            args += [flag(name, spec), str(value)]
    if "n_rays" not in names and method == "embree":
        args += ["--rays", "4"]
    return method, args, expect_usage


@FUZZ
@given(option_sets())
def test_bake_options_follow_one_rule(scene, case):
    src, n = scene
    method, args, expect_usage = case
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "o.ply"
        result = CliRunner().invoke(main, ["bake", str(src), "-o", str(out), "--method", method, "-q", *args])
        if expect_usage:
            assert result.exit_code == 2, (args, result.output)
            assert result.output.strip().splitlines()[-1].startswith("Error: ")
            assert list(Path(tmp).iterdir()) == []
        else:
            assert result.exit_code == 0, (args, result.output)
            ao = read_bake(out)
            assert ao.shape == (n,) and np.isfinite(ao).all() and ao.min() >= 0.0 and ao.max() <= 1.0
        assert "Traceback" not in result.output


_NAME_CHARS = st.sampled_from(list("abcXYZ019 -_.,@é+"))


@FUZZ
@given(
    stem=st.text(_NAME_CHARS, min_size=0, max_size=30),
    suffix=st.sampled_from([*BAKE_SUFFIXES, ".PLY", ".Usda", ".txt", ".ply.bak", "", ".", ".npz"]),
    repeat=st.integers(1, 8),
)
def test_output_names(scene, stem, suffix, repeat):
    """Any file name: a supported suffix bakes (long names included, up to 255 bytes);
    another is one line naming the output. Nothing else is left in the directory."""
    src, n = scene
    name = (stem * repeat)[:200] + suffix
    if not name or name in (".", "..") or len(name.encode()) > 255:
        return
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / name
        result = CliRunner().invoke(main, ["bake", str(src), "-o", str(out), "--rays", "4", "-q"])
        files = sorted(p.name for p in Path(tmp).iterdir())
        if out.suffix.lower() in BAKE_SUFFIXES:
            assert result.exit_code == 0, (name, result.output)
            assert files == [name]
            assert read_bake(out).shape == (n,)
        else:
            assert result.exit_code == 1, (name, result.output)
            assert result.output.startswith(f"Error: {name}: unsupported output suffix")
            assert result.output.count("\n") == 1
            assert files == []


def test_fuzz_model_knows_every_option():
    """The generators cover every option field (a new one needs a range here)."""
    for name, (spec, defaults) in FIELDS.items():
        assert set(defaults) <= set(METHODS)
        if spec.kind in (int, float):
            assert spec.low is not None or math.isinf(spec.high or math.inf), name


@pytest.mark.parametrize("value", ["0", "3"])
def test_an_option_the_method_does_not_take_is_refused_even_at_its_default(scene, tmp_path, value):
    src, _ = scene
    result = CliRunner().invoke(
        main, ["bake", str(src), "-o", str(tmp_path / "o.ply"), "--method", "bunnell", "--seed", value]
    )
    assert result.exit_code == 2
    assert result.output.strip().splitlines()[-1] == "Error: --seed does not apply to --method bunnell"
    assert list(tmp_path.iterdir()) == []
