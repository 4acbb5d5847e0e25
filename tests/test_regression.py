"""Results are pinned: every method on the bundled meshes at fixed options and seed.

``tests/data/regression.json`` holds, per case, the SHA-256 of the float64 result and
the platform it was recorded on; ``regression.npz`` holds the values (float64). On the
recorded platform (CPU model as LLVM names it, numba, numpy and embreex versions) the
results must be bit-identical. Elsewhere numba's vectorised float32 sums and Embree's
traversal may round differently, so the values must agree within that rounding
(deterministic methods) or differ at a few grazing rays only (Monte Carlo), and a
warning says the exact check was not possible.

The cases run in a fresh interpreter whose kernels load from numba's cache, as every
run but a kernel's first compilation does: a kernel's first, freshly compiled run can
differ in the last bits (numba optimises a ``parallel=True`` kernel's body again when it
caches it; measured: 1e-8 on passes >= 2 of the disk method). If a kernel had to compile
there, the cases run once more.

Regenerate after an intended change of results: ``python tests/test_regression.py``.
"""

from __future__ import annotations

import hashlib
import json
import platform
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).resolve().parents[1] / "data"
STORE = Path(__file__).resolve().parent / "data"

# name -> (mesh, method, options); "field" cases fit a field on the bunny and evaluate it
# on the mesh, placed beside it.
CASES = {}
for _mesh in ("bunny", "sphere_on_ground", "box_stack"):
    CASES[f"{_mesh}/embree"] = (_mesh, "embree", {})
    CASES[f"{_mesh}/embree-adaptive"] = (_mesh, "embree", {"n_rays": 64, "seed": 7, "tolerance": 0.05})
    CASES[f"{_mesh}/embree-uniform"] = (
        _mesh, "embree", {"n_rays": 32, "measure": "uniform", "max_distance": 0.5, "seed": 1},
    )
    CASES[f"{_mesh}/bunnell"] = (_mesh, "bunnell", {})
    CASES[f"{_mesh}/bunnell-passes2"] = (_mesh, "bunnell", {"passes": 2})
    CASES[f"{_mesh}/bunnell-passes3-theta4"] = (_mesh, "bunnell", {"passes": 3, "theta": 4.0})
    CASES[f"{_mesh}/bunnell-plain"] = (
        _mesh,
        "bunnell",
        {"directional": False, "near": 0.0, "measure": "uniform", "max_distance": 1.0},
    )
CASES["sphere_on_ground/field-raster"] = ("sphere_on_ground", "field", {"resolution": 8})
CASES["sphere_on_ground/field-embree"] = (
    "sphere_on_ground", "field", {"resolution": 8, "sampler": "embree", "n_rays": 64, "seed": 2},
)  # fmt: skip

# The bunny (+Y up, 9.7 tall) stands up (+Z) on the ground, 12 units along +x, the ground
# scaled by 8 to match it.
FIELD_PLACEMENT = (12.0, 0.0, 0.0, 90.0, 0.0, 0.0)


def platform_key() -> dict:
    """What decides the last bits of a result: CPU model, architecture, library versions."""
    import embreex
    import llvmlite.binding as llvm
    import numba

    return {
        "cpu": llvm.get_host_cpu_name(),
        "machine": platform.machine(),
        "numba": numba.__version__,
        "numpy": np.__version__,
        "embreex": getattr(embreex, "__version__", "unknown"),
    }


def compute(name: str) -> np.ndarray:
    """The float64 result of case ``name`` (see CASES)."""
    import aobake
    from aobake.io import load_mesh
    from aobake.methods.fields import field_ao, fit_field

    mesh, method, options = CASES[name]
    if method != "field":
        return np.asarray(aobake.bake(str(DATA / f"{mesh}.ply"), method, **options), dtype=np.float64)
    from aobake.methods.fields import rigid_transform

    field = fit_field(load_mesh(DATA / "bunny.ply"), **options)
    receiver = load_mesh(DATA / f"{mesh}.ply")
    placement = rigid_transform(FIELD_PLACEMENT[:3], FIELD_PLACEMENT[3:])
    return field_ao(field, receiver.positions * 8.0, receiver.normals, transform=placement)


def digest(values: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(values, dtype=np.float64).tobytes()).hexdigest()


def compiled_here() -> int:
    """Kernel specialisations this interpreter compiled instead of loading from the cache."""
    import aobake.kernels as kernels

    total = 0
    for module in list(sys.modules.values()):
        if getattr(module, "__name__", "").startswith(kernels.__name__ + "."):
            for value in vars(module).values():
                stats = getattr(value, "stats", None)
                if stats is not None and hasattr(stats, "cache_misses"):
                    total += sum(stats.cache_misses.values())
    return total


def compute_in_child() -> dict[str, np.ndarray]:
    """Every case computed in a fresh interpreter with cache-loaded kernels."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "values.npz"
        for _ in range(2):
            subprocess.run([sys.executable, __file__, "--compute", str(out)], check=True)
            with np.load(out) as z:
                values = {k: z[k] for k in z.files}
            if not values.pop("compiled_here"):
                return values
    raise AssertionError("kernels compiled again in a second interpreter: is numba's cache writable?")


@pytest.fixture(scope="module")
def computed():
    return compute_in_child()


@pytest.fixture(scope="module")
def stored():
    meta = json.loads((STORE / "regression.json").read_text())
    with np.load(STORE / "regression.npz") as z:
        values = {k: z[k] for k in z.files}
    return meta, values


def test_every_case_is_stored(stored):
    meta, values = stored
    assert sorted(meta["cases"]) == sorted(CASES)
    assert sorted(values) == sorted(k.replace("/", "__") for k in CASES)


@pytest.mark.parametrize("name", sorted(CASES))
def test_results_are_unchanged(stored, computed, name):
    meta, values = stored
    key = name.replace("/", "__")
    got, want = computed[key], values[key]
    assert got.shape == want.shape
    if platform_key() == meta["platform"]:
        assert digest(got) == meta["cases"][name], f"{name}: result changed on the recorded platform"
        np.testing.assert_array_equal(got, want)
        return
    warnings.warn(
        f"{name}: recorded on {meta['platform']}, running on {platform_key()}: "
        "checked within rounding, not bit for bit",
        stacklevel=1,
    )
    if CASES[name][1] == "embree":
        # a different traversal may flip a few grazing rays (and a contact's mirrored origin)
        differ = np.abs(got - want) > 1e-12
        assert differ.mean() <= 0.01, f"{name}: {differ.sum()} vertices differ"
        assert np.sqrt(np.mean((got - want) ** 2)) <= 0.01
    else:
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-5)


def write() -> None:
    """Compute every case and store the values, hashes and platform (run as a script)."""
    values = compute_in_child()
    cases = {}
    for name in sorted(CASES):
        result = values[name.replace("/", "__")]
        assert np.isfinite(result).all()
        cases[name] = digest(result)
        print(f"{name}: {cases[name][:16]} mean {result.mean():.6f}")
    STORE.mkdir(exist_ok=True)
    np.savez_compressed(STORE / "regression.npz", **values)
    meta = {"platform": platform_key(), "cases": cases}
    (STORE / "regression.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")


if __name__ == "__main__":
    if sys.argv[1:2] == ["--compute"]:
        out = {name.replace("/", "__"): compute(name) for name in sorted(CASES)}
        np.savez(sys.argv[2], compiled_here=np.array(compiled_here()), **out)
    else:
        write()
