"""Do results depend on the state of numba's cache? Bakes and fits tiny cases in fresh
interpreters sharing one new, empty numba cache: the first compiles every kernel, the
next load them from the cache (one of them on one thread), and compares the arrays bit
for bit (issue 19).

    python bench/cache_states.py [--cases bunnell,field] [--runs 3]

Run it from the checkout to check (``PYTHONPATH=...``). With both cases the first run
compiles for a few minutes of CPU (every variant of the disk method's tree pass), so the
test suite runs only the field case (``tests/test_cache_states.py``). Exit status 1
when an array differs between runs (still so for the disk method's passes >= 2, whose
tree pass keeps fastmath: docs/first-run.md).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

# label -> bunnell options; passes 1 and 2 run different tree-pass kernels
BUNNELL = {
    "bunnell": {},
    "bunnell-passes2": {"passes": 2},
    "bunnell-uniform": {"measure": "uniform", "max_distance": 0.5},
    "bunnell-uniform-passes2": {"measure": "uniform", "max_distance": 0.5, "passes": 2},
}


def compute(cases: list[str], path: str) -> None:
    """Writes every case's result to ``path`` (.npz)."""
    import aobake
    from aobake.methods.fields import field_ao, fit_field
    from aobake.testing import scenes

    s, _ = scenes.sphere_on_ground(0.5, 2, gap=0.0, cells=8)
    out = {}
    if "bunnell" in cases:
        for label, opts in BUNNELL.items():
            out[label] = np.asarray(aobake.bake(s, "bunnell", **opts))
    for case in cases:
        if case.startswith("field"):
            # "field-table" first fits the table model: a cache history for "field"
            for model in ("table", "cap") if case == "field" else (case.split("-")[1],):
                field = fit_field(s, resolution=6, model=model)
                out[f"field-{model}-texels"] = np.asarray(field.texels)
                out[f"field-{model}-residuals"] = np.asarray(field.residuals)
                points = s.positions * 0.3 + np.array([0.0, 0.0, 0.6])
                out[f"field-{model}-ao"] = field_ao(field, points, s.normals)
    np.savez(path, **out)


def _compute_in(cases: list[str], cache: str, out: Path, threads: int | None = None) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    if threads:
        env["NUMBA_NUM_THREADS"] = str(threads)
    subprocess.run([sys.executable, __file__, "--compute", str(out), "--cases", ",".join(cases)],
                   env=env, check=True)
    with np.load(out) as z:
        return {name: z[name] for name in z.files}


def run_states(cases: list[str], runs: int, work: str) -> list[dict[str, np.ndarray]]:
    """Fresh interpreters computing ``cases``; their results, in order: ``runs`` sharing
    one new numba cache (the first compiles, the last runs on one thread), then, with
    "field" among the cases, one whose new cache a table-model fit filled first (the cap
    fit then compiles against kernels loaded from the cache)."""
    results = []
    cache = Path(work) / "cache"
    for k in range(runs):
        threads = 1 if k == runs - 1 and runs > 2 else None
        results.append(_compute_in(cases, str(cache), Path(work) / f"run{k}.npz", threads))
    if "field" in cases:
        other = str(Path(work) / "other-cache")
        _compute_in(["field-table"], other, Path(work) / "table.npz")
        results.append(_compute_in(cases, other, Path(work) / "after-table.npz"))
    return results


def differences(results: list[dict[str, np.ndarray]]) -> list[str]:
    """One line per array that is not bit-identical to the first run's."""
    lines = []
    for k, res in enumerate(results[1:], 1):
        for name, a in results[0].items():
            b = res[name]
            if a.shape != b.shape or a.tobytes() != b.tobytes():
                lines.append(f"run {k}: {name} differs, max |diff| {np.abs(a - b).max():.3g}")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="bunnell,field")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--compute", metavar="OUT", help=argparse.SUPPRESS)
    args = parser.parse_args()
    cases = args.cases.split(",")
    if args.compute:
        compute(cases, args.compute)
        return 0
    with tempfile.TemporaryDirectory(prefix="aobake-cache-") as work:
        results = run_states(cases, args.runs, work)
    lines = differences(results)
    n = sum(len(r) for r in results[1:])
    print(f"{n - len(lines)} of {n} arrays bit-identical to the first (compiling) run")
    for line in lines:
        print("  " + line)
    return 1 if lines else 0


if __name__ == "__main__":
    sys.exit(main())
