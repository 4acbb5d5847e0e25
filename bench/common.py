"""Shared helpers for the benchmarks: cached scenes, timers, error metrics and Markdown tables.

Every number a benchmark reports should be a ratio of timings taken in the same run
(the bench machine is shared and noisy); :func:`interleaved` runs the contenders in
round-robin order so that load spikes hit all of them alike, and keeps the best of the
repeats for each.
"""

from __future__ import annotations

import gc
import math
import os
import platform
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from aobake.testing import scenes

ROOT = Path(__file__).resolve().parent.parent
DATA_DIR = ROOT / "data"
RESULTS_DIR = Path(__file__).resolve().parent / "results"  # gitignored

#: Bump when a large scene of aobake.testing.scenes changes, so stale caches are not reused.
SCENE_VERSION = 1


# --------------------------------------------------------------------------- scenes


@dataclass
class BenchScene:
    """A named surface with a flag saying whether it counts as a "small" mesh."""

    name: str
    surface: Any  # aobake.mesh.Surface
    small: bool

    @property
    def n_vertices(self) -> int:
        return self.surface.n_vertices


def load_surface(path: Path):
    """The project's ``load_mesh`` (wherever it lives now), else trimesh (``process=False``)."""
    import importlib

    for module in ("aobake.io", "aobake.mesh"):
        try:
            load_mesh = importlib.import_module(module).load_mesh
        except (ImportError, AttributeError):
            continue
        try:
            return load_mesh(path)
        except Exception:  # the loader is still being written: fall through to trimesh
            break
    import trimesh

    from aobake.mesh import surface_from_arrays

    m = trimesh.load(path, process=False, force="mesh")
    return surface_from_arrays(m.vertices, m.faces, name=path.stem, source=path.name)


def data_scenes(data_dir: Path = DATA_DIR) -> list[BenchScene]:
    """Every ``*.ply`` in ``data/`` (read now: files may still be appearing), small ones."""
    out = []
    for path in sorted(Path(data_dir).glob("*.ply")):
        try:
            out.append(BenchScene(path.stem, load_surface(path), small=True))
        except Exception as exc:  # a half-written file: skip it, say so
            print(f"(skipping {path.name}: {type(exc).__name__}: {exc})")
    return out


def bunny_on_ground(n_vertices: int = 700_000, *, cache: bool = True) -> tuple[Any, str]:
    """data/bunny.ply on a floor (aobake.testing.scenes.bunny_on_ground_arrays) as a
    Surface, cached as .npz under bench/results/."""

    def arrays(n):
        bunny = load_surface(DATA_DIR / "bunny.ply")
        return scenes.bunny_on_ground_arrays(bunny.positions, bunny.faces, n)

    return _cached_scene("bunny_on_ground", "bunny", n_vertices, arrays, cache)


def spheres_on_ground(n_vertices: int = 700_000, *, cache: bool = True) -> tuple[Any, str]:
    """Four balls in a block on a floor (aobake.testing.scenes.spheres_in_block_arrays) as
    a Surface, cached as .npz under bench/results/."""
    return _cached_scene("spheres_on_ground", "spheres", n_vertices, scenes.spheres_in_block_arrays, cache)


def _cached_scene(key, name, n_vertices, arrays, cache):
    from aobake.mesh import surface_from_arrays

    path = RESULTS_DIR / f"{key}_v{SCENE_VERSION}_{n_vertices}.npz"
    if cache and path.exists():
        z = np.load(path, allow_pickle=False)
        surface = surface_from_arrays(z["positions"], z["faces"], z["normals"], name=name)
        return surface, str(z["desc"])
    positions, faces, desc = arrays(n_vertices)
    surface = surface_from_arrays(positions, faces, name=name)
    if cache:
        RESULTS_DIR.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
        np.savez(tmp, positions=surface.positions, faces=surface.faces, normals=surface.normals,
                 desc=desc)
        os.replace(tmp, path)
    return surface, desc


# --------------------------------------------------------------------------- timing


@dataclass
class Timing:
    """Best wall time of the repeats, with the CPU time of that same repeat."""

    seconds: float
    cpu: float
    result: Any = None
    repeats: int = 1
    #: Every repeat's return value, when asked for (stochastic methods: average their error).
    results: list = field(default_factory=list)

    @property
    def cores(self) -> float:
        """Process CPU time / wall time: how many cores were busy on average."""
        return self.cpu / self.seconds if self.seconds > 0 else float("nan")


def timed(fn: Callable[[], Any]) -> Timing:
    """One run of ``fn``: wall and process CPU time (all threads)."""
    gc.collect()
    c0, t0 = time.process_time(), time.perf_counter()
    result = fn()
    t1, c1 = time.perf_counter(), time.process_time()
    return Timing(t1 - t0, c1 - c0, result)


def best_of(fn: Callable[[], Any], repeats: int = 3) -> Timing:
    """Best (minimum wall time) of ``repeats`` runs; ``result`` is that run's return value."""
    return interleaved({"fn": fn}, repeats)["fn"]


def interleaved(
    fns: dict[str, Callable[[], Any]],
    repeats: int = 3,
    *,
    short: float = 0.1,
    max_repeats: int = 7,
    keep: Callable[[Any], Any] | None = None,
) -> dict[str, Timing]:
    """Run every function once per round, ``repeats`` rounds; best Timing per key.

    Round-robin order means a burst of load from another process slows all contenders
    of a round, not just one of them, and the minimum filters it out. Runs shorter than
    ``short`` seconds (tiny meshes, where scheduler noise is as large as the run) get
    extra rounds, up to ``max_repeats``. With ``keep``, ``keep(result)`` of every run is
    collected in ``Timing.results`` (outside the timed region).
    """
    best: dict[str, Timing] = {}
    kept: dict[str, list] = {key: [] for key in fns}
    rounds = 0
    while rounds < max(1, repeats) or (
        rounds < max_repeats and max(t.seconds for t in best.values()) < short
    ):
        for key, fn in fns.items():
            t = timed(fn)
            if keep is not None:
                kept[key].append(keep(t.result))
            if key not in best or t.seconds < best[key].seconds:
                best[key] = t
        rounds += 1
    for key, t in best.items():
        t.repeats = rounds
        t.results = kept[key]
    return best


def runnable_threads(script: str, *, interval: float = 0.005) -> tuple[float, int]:
    """Mean and max number of runnable threads of a child Python process while it works.

    ``script`` runs in a fresh interpreter (this file's directory on ``sys.path``); it
    prints ``GO`` once set up, then does the work to observe and exits. Threads in state
    R (running or waiting for a core) are counted from ``/proc`` every ``interval``
    seconds, so the count says how many threads a library keeps busy even when other
    processes take the cores. Returns (nan, 0) where ``/proc`` is unavailable.
    """
    import subprocess
    import sys

    if not Path("/proc/self/task").exists():
        return float("nan"), 0
    env = dict(os.environ)
    paths = [str(ROOT), str(Path(__file__).resolve().parent), env.get("PYTHONPATH", "")]
    env["PYTHONPATH"] = os.pathsep.join(p for p in paths if p)
    proc = subprocess.Popen(
        [sys.executable, "-c", script], stdout=subprocess.PIPE, env=env, text=True
    )
    counts = []
    try:
        if proc.stdout.readline().strip() != "GO":
            proc.wait()
            return float("nan"), 0
        tasks = Path(f"/proc/{proc.pid}/task")
        while proc.poll() is None:
            n = 0
            try:
                for t in tasks.iterdir():
                    try:
                        stat = (t / "stat").read_text()
                    except OSError:
                        continue
                    n += stat[stat.rindex(")") + 2] == "R"
            except OSError:
                break
            counts.append(n)
            time.sleep(interval)
    finally:
        proc.wait()
    if not counts:
        return float("nan"), 0
    return float(np.mean(counts)), int(max(counts))


# --------------------------------------------------------------------------- errors


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((np.asarray(a, float) - np.asarray(b, float)) ** 2)))


def time_at_error(points: list[tuple[float, float]], target: float) -> tuple[float, str]:
    """Time needed for RMSE ``target``, log-log interpolated between (seconds, rmse) points.

    Points are taken in order of increasing time; the first segment whose errors bracket
    the target is used. Returns (seconds, flag): flag "" (interpolated), ">" (the target
    was not reached: the slowest point's time, a lower bound), "<" (even the fastest
    point beats the target: its time, an upper bound) or "?" (no usable points). No
    extrapolation: error curves are not power laws far from the data (libigl's is not
    even monotone: it stratifies only square sample counts).
    """
    pts = sorted((t, e) for t, e in points if t > 0 and e > 0 and math.isfinite(e))
    if not pts or not math.isfinite(target) or target <= 0:
        return float("nan"), "?"
    if pts[0][1] <= target:
        return pts[0][0], "<"
    y = math.log(target)
    for (t0, e0), (t1, e1) in zip(pts[:-1], pts[1:], strict=True):
        if min(e0, e1) <= target <= max(e0, e1) and e0 != e1:
            f = (y - math.log(e0)) / (math.log(e1) - math.log(e0))
            return float(math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0)))), ""
    return pts[-1][0], ">"


def bounded_ratio(num: tuple[float, str], den: tuple[float, str]) -> tuple[float, str]:
    """num / den for two :func:`time_at_error` results, with the bound that follows."""
    (a, fa), (b, fb) = num, den
    if "?" in (fa, fb) or not (b > 0):
        return float("nan"), "?"
    up = {"": 0, ">": 1, "<": -1}  # direction each value may move
    d = up[fa] - up[fb]
    if up[fa] and up[fb] and up[fa] == up[fb]:
        return a / b, "?"
    return a / b, (">" if d > 0 else "<" if d < 0 else "")


# --------------------------------------------------------------------------- printing


def markdown_table(headers: list[str], rows: list[list[Any]], align: str | None = None) -> str:
    """A GitHub Markdown table; ``align`` is one of l/r per column (default: l then r)."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    align = align or ("l" + "r" * (len(headers) - 1))

    def line(r):
        cols = zip(r, widths, align, strict=True)
        padded = (c.ljust(w) if a == "l" else c.rjust(w) for c, w, a in cols)
        return "| " + " | ".join(padded) + " |"

    rule = {"r": lambda w: "-" * (w + 1) + ":", "l": lambda w: ":" + "-" * (w + 1)}
    sep = "|" + "|".join(rule[a](w) for w, a in zip(widths, align, strict=True)) + "|"
    return "\n".join([line(cells[0]), sep] + [line(r) for r in cells[1:]])


def print_table(title: str, headers: list[str], rows: list[list[Any]], note: str = "") -> None:
    print(f"\n### {title}\n")
    print(markdown_table(headers, rows))
    if note:
        print(f"\n{note}")


def fmt_rate(rays: float, seconds: float) -> str:
    """Rays per second in M rays/s."""
    return f"{rays / seconds / 1e6:.2f}" if seconds > 0 else "-"


def fmt_s(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "-"
    return f"{seconds:.3f}" if seconds < 10 else f"{seconds:.1f}"


def fmt_ratio(x: float, goal: float | None = None, bound: str = "") -> str:
    """``x`` with a goal mark; ``bound`` ">"/"<" prefixes it (a bound, not a value)."""
    if not math.isfinite(x) or bound == "?":
        return "-"
    if goal is None:
        mark = ""
    elif bound == ">":
        mark = " ✓" if x >= goal else " ?"
    elif bound == "<":
        mark = " ✗" if x < goal else " ?"
    else:
        mark = " ✓" if x >= goal else " ✗"
    return f"{bound}{x:.2f}{mark}"


def machine_facts() -> list[tuple[str, str]]:
    """(label, value) pairs: cores, affinity, numba threads, library versions."""
    import numba

    facts = [
        ("CPU", platform.processor() or platform.machine()),
        ("os.cpu_count()", str(os.cpu_count())),
    ]
    try:
        facts.append(("cores usable (affinity)", str(len(os.sched_getaffinity(0)))))
    except AttributeError:
        pass
    threads = f"{numba.get_num_threads()} (NUMBA_NUM_THREADS={numba.config.NUMBA_NUM_THREADS})"
    facts.append(("numba threads", threads))
    for mod in ("embreex", "numba", "numpy", "trimesh"):
        facts.append((mod, _version(mod)))
    facts.append(("libigl", _version("libigl")))
    facts.append(("python", platform.python_version()))
    try:
        facts.append(("load average (1 min) at start", f"{os.getloadavg()[0]:.2f}"))
    except OSError:
        pass
    return facts


def _version(dist: str) -> str:
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "not installed"
