"""The architecture as rules: import direction between layers, one room per method, and
which module may import which heavy library. Checked on the source (AST) and, for the
light imports, in fresh interpreters."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "aobake"

# Layer of each module, by the longest matching dotted prefix (relative to aobake).
# Lower layers never import higher ones.
LAYERS = {
    "constants": 0, "errors": 0, "_types": 0, "checks": 0, "options": 0, "lazy": 0,
    "kernels": 1,
    "mesh": 2, "sampling": 2, "progress": 2, "shading": 2, "ground": 2, "precompile": 2,
    "tracing": 3, "contacts": 3, "plan": 3, "selection": 3,
    "io": 3,
    "methods": 4,
    "pipeline": 5, "lighting": 5, "tools": 5, "testing": 5, "batch": 5,
    "cli": 6, "__main__": 6, "__init__": 6,
}  # fmt: skip

# Each method's room: modules in one may not import another's.
ROOMS = ("methods.embree", "methods.bunnell", "methods.fields")

# The only modules that may import these libraries (prefixes).
OWNERS = {
    "embreex": ("tracing",),
    "trimesh": ("io.trimesh_formats", "testing"),  # testing: procedural scenes (icospheres, boxes)
    "dask": ("batch",),
    "distributed": ("batch",),
}


def module_name(path: Path) -> str:
    """``aobake/methods/embree/options.py`` -> ``methods.embree.options``;
    ``aobake/methods/__init__.py`` -> ``methods``; ``aobake/__init__.py`` -> ``__init__``."""
    parts = list(path.relative_to(PACKAGE).with_suffix("").parts)
    if parts[-1] == "__init__" and len(parts) > 1:
        parts = parts[:-1]
    return ".".join(parts)


def _exists(dotted: str) -> bool:
    base = PACKAGE.joinpath(*dotted.split("."))
    return base.with_suffix(".py").exists() or (base / "__init__.py").exists()


def imports(path: Path) -> list[str]:
    """aobake-internal modules ``path`` imports (relative or absolute, anywhere in it),
    as dotted names relative to aobake."""
    own = module_name(path)
    package = own.split(".") if path.name == "__init__.py" and own != "__init__" else own.split(".")[:-1]
    if own == "__init__":
        package = []
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                if node.module:
                    found.append(".".join(base + node.module.split(".")))
                else:
                    for alias in node.names:
                        if alias.name == "__version__":
                            continue  # the version string of the package: no layer
                        sub = ".".join(base + [alias.name])
                        found.append(sub if _exists(sub) else ".".join(base) or "__init__")
            elif node.module and node.module.startswith("aobake."):
                found.append(node.module[len("aobake.") :])
            elif node.module == "aobake":
                found.append("__init__")
        elif isinstance(node, ast.Import):
            found += [a.name[len("aobake.") :] for a in node.names if a.name.startswith("aobake.")]
    return found


def layer(name: str) -> int:
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        key = ".".join(parts[:k])
        if key in LAYERS:
            return LAYERS[key]
    return -1


def room(name: str) -> str | None:
    return next((r for r in ROOMS if name == r or name.startswith(r + ".")), None)


SOURCES = sorted(PACKAGE.rglob("*.py"))


@pytest.mark.parametrize("path", SOURCES, ids=module_name)
def test_no_module_imports_a_higher_layer(path):
    own = layer(module_name(path))
    assert own >= 0, f"{module_name(path)} has no layer in tests/test_layers.py"
    for name in imports(path):
        if name == "__init__" and own == 6:
            continue
        assert layer(name) <= own, f"{module_name(path)} (layer {own}) imports {name} (layer {layer(name)})"


@pytest.mark.parametrize("path", SOURCES, ids=module_name)
def test_methods_never_import_each_other(path):
    mine = room(module_name(path))
    if mine is None:
        return  # the registry, pipeline and tools may use any method
    for name in imports(path):
        other = room(name)
        assert other is None or other == mine, f"{module_name(path)} imports {name} of {other}"


@pytest.mark.parametrize("path", SOURCES, ids=module_name)
def test_only_tests_and_bench_use_the_testing_package(path):
    if module_name(path).startswith("testing"):
        return
    for name in imports(path):
        assert not name.startswith("testing"), f"{module_name(path)} imports {name}"


@pytest.mark.parametrize("path", sorted((PACKAGE / "kernels").rglob("*.py")), ids=module_name)
def test_kernels_import_only_kernels_and_constants(path):
    for name in imports(path):
        assert name == "constants" or name.startswith("kernels"), f"{module_name(path)} imports {name}"


def _external(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            names.add(node.module.split(".")[0])
    return names


@pytest.mark.parametrize("library", sorted(OWNERS))
def test_heavy_libraries_have_one_owner(library):
    for path in SOURCES:
        name = module_name(path)
        if library in _external(path):
            assert name.startswith(OWNERS[library]), f"{name} imports {library}"


def test_the_layer_test_sees_imports():
    # the resolver itself: a relative import three levels up, and a sibling module
    names = imports(PACKAGE / "methods" / "embree" / "options.py")
    assert "options" in names
    assert "methods.embree.options" in imports(PACKAGE / "methods" / "embree" / "__init__.py")


def _loaded_after(statement: str) -> set[str]:
    code = f"import sys; {statement}; print(' '.join(sorted(sys.modules)))"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    return set(out.split())


HEAVY = {"numpy", "numba", "trimesh", "embreex", "pxr", "matplotlib", "dask", "distributed"}


@pytest.mark.parametrize(
    "statement",
    ["import aobake", "import aobake.cli", "import aobake.methods", "import aobake.options", "import aobake.batch"],
)
def test_light_imports(statement):
    loaded = _loaded_after(statement)
    assert not HEAVY & loaded, f"`{statement}` pulls in {sorted(HEAVY & loaded)}"


@pytest.mark.parametrize("module", ["tools.compare", "tools.sweep", "tools.preview"])
def test_tools_import_matplotlib_lazily(module):
    assert "matplotlib" not in _loaded_after(f"import aobake.{module}")


def test_io_import_is_light():
    loaded = _loaded_after("import aobake.io")
    assert not {"trimesh", "pxr"} & loaded, "trimesh and pxr are imported inside functions only"


@pytest.mark.parametrize(
    "module", sorted(module_name(p) for p in (PACKAGE / "kernels").rglob("*.py") if p.stem != "__init__")
)
def test_kernels_import_nothing_heavy(module):
    loaded = _loaded_after(f"import aobake.{module}")
    assert not {"trimesh", "embreex", "pxr", "click"} & loaded


def test_bake_without_fields_loads_no_field_code():
    # a bake without --field checks its (empty) field list: that must not import the
    # field method's modules or kernels (0.6 s on every bake)
    loaded = _loaded_after("import aobake.pipeline as p; p._load_fields(())")
    field_code = {m for m in loaded if m.startswith(("aobake.methods.fields.", "aobake.kernels.field"))}
    assert field_code <= {"aobake.methods.fields.options"}, sorted(field_code)
    loaded = _loaded_after("import aobake.pipeline as p; p._load_fields([])")
    assert "aobake.kernels.field_eval" not in loaded


def test_kernels_load_without_scipy_linalg():
    # numba's arraymath imports scipy.linalg (~0.2 s) only to learn that BLAS exists;
    # aobake.kernels answers that (as numba would) without the import: a kernel loads
    # without it, numba still knows BLAS, and np.dot in a kernel still uses it. Without
    # scipy installed (it is not among aobake's dependencies) numba has no BLAS either way.
    import importlib.util

    if importlib.util.find_spec("scipy") is None:
        code = (
            "import sys, numpy as np; from aobake.kernels import topology as t; "
            "t.longest_edges(np.eye(3), np.array([[0, 1, 2]])); "
            "import numba.np.arraymath as a; print('scipy.linalg' in sys.modules, a._HAVE_BLAS)"
        )
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        assert out.stdout.split() == ["False", "False"], out.stdout
        return
    code = (
        "import sys, numpy as np; from aobake.kernels import topology as t; "
        "t.longest_edges(np.eye(3), np.array([[0, 1, 2]])); "
        "print('scipy.linalg' in sys.modules); "
        "import numba.np.arraymath as a, numba.np.linalg as l; print(a._HAVE_BLAS); "
        "print(a.ensure_blas is l.ensure_blas and l.ensure_blas.__module__ == 'numba.np.linalg'); "
        "from numba import njit; f = njit(lambda a, b: np.dot(a, b)); "
        "print(f(np.ones((2, 3)), np.ones((3, 2)))[0, 0], 'scipy.linalg' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "True", "True", "3.0", "True"], out.stdout
