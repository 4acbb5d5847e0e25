"""Import-direction rules (STYLE.md 3.3), checked in fresh interpreters."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "aobake"

LAYERS = {
    "constants": 0, "errors": 0, "_types": 0,
    "kernels": 1,
    "mesh": 2, "sampling": 2, "progress": 2, "io_common": 2, "ply": 2, "readers": 2,
    "raytrace": 3, "bunnell": 3, "field": 3, "raster": 3, "hierarchy": 3, "hybrid": 3,
    "io_ply": 4, "io_usd": 4, "formats": 4, "preview": 4,
    "pipeline": 5, "compare": 5, "sweep": 5,
    "cli": 6, "__main__": 6, "__init__": 6,
}  # fmt: skip


def _loaded_after(statement: str) -> set[str]:
    code = f"import sys; {statement}; print(' '.join(sorted(sys.modules)))"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    return set(out.split())


def test_cli_import_is_light():
    loaded = _loaded_after("import aobake.cli")
    for heavy in ("numpy", "numba", "trimesh", "embreex", "pxr", "matplotlib"):
        assert heavy not in loaded, f"`import aobake.cli` pulls in {heavy}"


def test_readers_import_is_light():
    loaded = _loaded_after("import aobake.readers")
    assert not {"trimesh", "pxr"} & loaded, "trimesh and pxr are imported inside functions only"


def test_package_import_is_light():
    loaded = _loaded_after("import aobake")
    assert not {"numba", "trimesh", "embreex", "pxr"} & loaded


@pytest.mark.parametrize(
    "module", sorted(p.stem for p in (PACKAGE / "kernels").glob("*.py") if p.stem != "__init__")
)
def test_kernels_import_nothing_heavy(module):
    loaded = _loaded_after(f"import aobake.kernels.{module}")
    assert not {"trimesh", "embreex", "pxr", "click"} & loaded


def _imports(path: Path) -> list[str]:
    """aobake-internal modules imported by ``path`` (relative or absolute, anywhere in it)."""
    tree = ast.parse(path.read_text())
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:  # relative
                base = node.module or ""
                names = [base] if base else [a.name for a in node.names]
                found += [n.split(".")[0] for n in names]
            elif node.module and node.module.startswith("aobake."):
                found.append(node.module.split(".")[1])
        elif isinstance(node, ast.Import):
            found += [a.name.split(".")[1] for a in node.names if a.name.startswith("aobake.")]
    return found


def _layer(name: str) -> int:
    return LAYERS.get(name, LAYERS.get(name.split(".")[0], -1))


@pytest.mark.parametrize("path", sorted(PACKAGE.glob("*.py")), ids=lambda p: p.stem)
def test_no_module_imports_a_higher_layer(path):
    own = _layer(path.stem)
    assert own >= 0, f"{path.name} has no layer in tests/test_layers.py"
    for name in _imports(path):
        if name == "__version__":
            continue
        assert _layer(name) <= own, (
            f"{path.name} (layer {own}) imports {name} (layer {_layer(name)})"
        )


@pytest.mark.parametrize("path", sorted((PACKAGE / "kernels").glob("*.py")), ids=lambda p: p.stem)
def test_kernels_import_only_kernels_and_constants(path):
    for name in _imports(path):
        assert name in {"constants"} or (PACKAGE / "kernels" / f"{name}.py").exists(), (
            f"{path.name} imports {name}"
        )


def _external(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_only_raytrace_imports_embreex_and_only_readers_imports_trimesh():
    for path in PACKAGE.rglob("*.py"):
        ext = _external(path)
        if path.stem != "raytrace":
            assert "embreex" not in ext, path
        if path.stem != "readers":
            assert "trimesh" not in ext, path
