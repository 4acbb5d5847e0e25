"""Whole-process benchmark: ``aobake bake`` as a user runs it, against bare embreex.

Run from the repository root::

    PYTHONPATH=. python bench/bench_process.py                      # 721k scene (~5 min)
    PYTHONPATH=. python bench/bench_process.py --baseline ../main   # also another checkout
    PYTHONPATH=. python bench/bench_process.py --big --huge         # + ~3.7M and ~27M scenes

Scenes: an icosphere (radius 0.5, its lowest vertex on the floor) over a square grid
floor, written as binary little-endian PLY (float32 x y z, uchar/int faces) and cached
under bench/results/: subdivision 8 over 256^2 cells (721,411 vertices), with ``--big``
subdivision 9 over 1024^2 (3,672,067), with ``--huge`` subdivision 10 over 4096^2
(27,271,171; skipped when MemAvailable is short; this tree's embree rows, one run each).
``--big-rows`` limits the rows of the larger scenes.

1. Whole process: ``python -m aobake bake SCENE -o out.ply --up Z`` in a fresh process
   (warm numba cache) at --rays 1, 16, 64 and ``--method bunnell`` at its defaults:
   wall time, peak RSS (VmHWM at exit), bytes of peak RSS per vertex. On the 721k scene
   against bare embreex tracing the very same rays (origins from ``contact_origins``,
   directions from ``sample_directions``, prepared beforehand, same chunks, same thread
   count): the ratio is the process overhead the issue's goals bound.
2. Stage shares: one run of each configuration under cProfile in a fresh process; the
   cumulative time of each stage function as a share of the whole (the profiler slows
   Python-heavy stages more than native ones: shares, not seconds). With ``--stages``
   instead: the wall time of each stage from ``perf_counter`` marks around the stage
   functions in a fresh process (no profiler), median of ``--repeats`` round-robin runs.

3. Against libigl (721k scene, when ``igl`` is installed): a fresh process running the
   shortest libigl script of the same bake, ``read_triangle_mesh``, ``per_vertex_normals``,
   ``embree.ambient_occlusion`` at 64 rays (uniform hemisphere, from points lifted as
   bench_embree lifts them), the result saved as .npy (less than our PLY writer does);
   beside it ``aobake bake --rays 64 --measure uniform`` and Bunnell at its defaults,
   with libigl's wall time over theirs.

Every ratio is of timings taken in this run, round-robin, best of ``--repeats``.
"""

from __future__ import annotations

import argparse
import os
import pstats
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import common as C

#: (label, bake arguments) of the whole-process rows.
CONFIGS = [
    ("embree --rays 1", ["--rays", "1", "--seed", "0"]),
    ("embree --rays 16", ["--rays", "16", "--seed", "0"]),
    ("embree --rays 64", ["--rays", "64", "--seed", "0"]),
    ("bunnell (defaults)", ["--method", "bunnell"]),
]
#: name -> (icosphere subdivisions, floor cells, vertices)
SCENES = {
    "721k": (8, 256, 721_411),
    "3.7M": (9, 1024, 3_672_067),
    "27M": (10, 4096, 27_271_171),
}
#: Stage -> the functions whose cumulative time it is (first found counts).
STAGES = [
    ("read", ("read_parts", "load_mesh")),
    ("normals", ("angle_weighted_normals",)),
    ("scene build", ("build@tracing.py", "__init__@tracing.py")),  # build: since Tracer.build
    ("contacts", ("contact_origins", "contact_points")),
    ("rays + trace", ("trace_chunks",)),
    ("bunnell", ("run@bunnell",)),
    ("write", ("write_bake",)),
]
GOALS = {"embree --rays 16": 1.3, "embree --rays 64": 1.1}
#: Rows set against libigl's whole process at 64 uniform rays (goal: libigl / ours).
IGL_ROWS = [
    ("embree --rays 64 --measure uniform", ["--rays", "64", "--seed", "0", "--measure", "uniform"]),
    ("bunnell (defaults)", ["--method", "bunnell"]),
]
IGL_GOAL = 1.5
SEED = 0  # the --seed of the embree rows


def log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def write_binary_ply(path: Path, positions: np.ndarray, faces: np.ndarray) -> None:
    """A binary little-endian PLY: float32 x y z, faces as uchar count + 3 int32."""
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(positions)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    rec = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    rec["n"] = 3
    rec["i"] = faces
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    with open(tmp, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(np.ascontiguousarray(positions, dtype="<f4").tobytes())
        f.write(rec.tobytes())
    os.replace(tmp, path)


def scene_file(name: str) -> Path:
    """The cached binary PLY of scene ``name`` (built on first use)."""
    sub, cells, _ = SCENES[name]
    path = C.RESULTS_DIR / f"process_sphere{sub}_floor{cells}.ply"
    if not path.exists():
        from aobake.testing import scenes

        log(f"building the {name} scene (icosphere {sub}, floor {cells}^2)")
        surface, _ = scenes.sphere_on_ground(0.5, sub, cells=cells)
        C.RESULTS_DIR.mkdir(parents=True, exist_ok=True)
        write_binary_ply(path, surface.positions, surface.faces)
    return path


def mem_available() -> int:
    """Bytes of MemAvailable (/proc/meminfo), or 0 when unknown."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


#: The child's script: runs ``aobake`` and, at exit, copies its /proc status (VmHWM: the
#: peak resident set of this process image; ``wait4``'s ru_maxrss would include the
#: parent's memory at fork time).
LAUNCH = """import atexit, runpy, shutil, sys
atexit.register(shutil.copyfile, "/proc/self/status", sys.argv.pop(1))
sys.argv[0] = "aobake"
runpy.run_module("aobake", run_name="__main__")
"""


#: The child's script for ``--stages``: :data:`LAUNCH` with ``perf_counter`` marks around
#: the stage functions (those the checkout has), written as JSON at exit: per stage its
#: wall seconds (calls summed), ``imports`` (the CLI's start to the bake's), ``kernels``
#: (numba loading cached kernels, inside the stages) and ``process`` (the script's start
#: to exit; the interpreter's start is the rest of the measured wall).
STAGE_LAUNCH = """import time
T0 = time.perf_counter()
import atexit, functools, importlib, json, runpy, shutil, sys
status, marks_path = sys.argv.pop(1), sys.argv.pop(1)
atexit.register(shutil.copyfile, "/proc/self/status", status)
marks = {}
WRAP = %r

def add(label, t):
    marks[label] = marks.get(label, 0.0) + time.perf_counter() - t

def wrapped(fn, label):
    @functools.wraps(fn)
    def w(*a, **k):
        t = time.perf_counter()
        try:
            return fn(*a, **k)
        finally:
            add(label, t)
    return w

def install(name):
    module = sys.modules[name]
    for mod, attr, label in WRAP:
        if mod != name:
            continue
        owner, parts = module, attr.split(".")
        for p in parts[:-1]:
            owner = getattr(owner, p, None)
        if owner is not None and callable(getattr(owner, parts[-1], None)):
            setattr(owner, parts[-1], wrapped(getattr(owner, parts[-1]), label))
    if name == "numba.core.dispatcher":
        cls = module.Dispatcher
        cls._compile_for_args = wrapped(cls._compile_for_args, "kernels")
    if name == "aobake.pipeline":
        marks["imports"] = time.perf_counter() - T0

class Finder:  # wraps each module of WRAP as soon as it is imported
    names = {m for m, _, _ in WRAP} | {"numba.core.dispatcher"}

    def find_spec(self, name, path=None, target=None):
        if name not in self.names:
            return None
        self.names.discard(name)
        spec = importlib.util.find_spec(name)
        loader = spec.loader
        run = loader.exec_module

        def exec_module(module):
            run(module)
            install(name)
        loader.exec_module = exec_module
        return spec

import importlib.util
sys.meta_path.insert(0, Finder())

def dump():
    marks["process"] = time.perf_counter() - T0
    with open(marks_path, "w") as f:
        json.dump(marks, f)
atexit.register(dump)
sys.argv[0] = "aobake"
runpy.run_module("aobake", run_name="__main__")
"""
#: (module, attribute, stage) wrapped by :data:`STAGE_LAUNCH`; a stage's calls are summed.
STAGE_MARKS = [
    ("aobake.io.ply", "read_parts", "read"),
    ("aobake.mesh", "angle_weighted_normals", "normals"),
    ("aobake.tracing", "Tracer.build", "scene build"),
    ("aobake.methods.embree.estimator", "contact_origins", "contacts"),
    ("aobake.methods.embree.estimator", "trace_chunks", "rays + trace"),
    ("aobake.io", "write_bake", "write"),
    ("aobake.pipeline", "bake_file", "bake"),
]


def run_bake(code: str, ply: Path, args: list[str], out_dir: str, profile: Path | None = None,
             marks: Path | None = None):  # fmt: skip
    """(wall seconds, peak RSS bytes) of one ``aobake bake`` in a fresh process that
    imports aobake from the checkout ``code`` (its working directory and PYTHONPATH);
    ``profile``: under cProfile, to that file; ``marks``: :data:`STAGE_LAUNCH`'s stage
    times to that JSON file."""
    env = dict(os.environ, PYTHONPATH=code)
    status, launch = os.path.join(out_dir, "status"), Path(out_dir) / "launch.py"
    launch.write_text(LAUNCH if marks is None else STAGE_LAUNCH % (STAGE_MARKS,))
    cmd = [sys.executable]
    if profile is not None:
        cmd += ["-m", "cProfile", "-o", str(profile)]
    cmd += [str(launch), status] + ([] if marks is None else [str(marks)]) + ["bake", str(ply), "-o", os.path.join(out_dir, "out.ply"),
            "--up", "Z", "--quiet", *args]  # fmt: skip
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, cwd=code, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        err = proc.stderr.decode(errors="replace").strip()
        raise SystemExit(f"aobake bake {' '.join(args)} failed ({proc.returncode}): {err}")
    if marks is not None:  # the process's CPU time (all its threads), which load inflates less
        import json

        got = json.loads(Path(marks).read_text())
        got["cpu"] = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        Path(marks).write_text(json.dumps(got))
    peak = 0
    for line in Path(status).read_text().splitlines():
        if line.startswith("VmHWM:"):
            peak = int(line.split()[1]) * 1024
    return wall, peak


#: libigl's whole process: read, vertex normals, AO at N uniform rays, save (see 3.).
LIBIGL = """import atexit, shutil, sys
atexit.register(shutil.copyfile, "/proc/self/status", sys.argv[1])
import numpy as np
import igl
import igl.embree
V, F = igl.read_triangle_mesh(sys.argv[2])
N = igl.per_vertex_normals(V, F)
P = V + 1e-5 * (np.abs(V).max() + 1.0) * N
np.save(sys.argv[3], 1.0 - igl.embree.ambient_occlusion(V, F, P, N, int(sys.argv[4])))
"""


def run_libigl(ply: Path, n_rays: int, out_dir: str):
    """(wall seconds, peak RSS bytes) of :data:`LIBIGL` in a fresh process."""
    status, script = os.path.join(out_dir, "status"), Path(out_dir) / "libigl.py"
    script.write_text(LIBIGL)
    cmd = [sys.executable, str(script), status, str(ply), os.path.join(out_dir, "ao.npy"), str(n_rays)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"libigl failed ({proc.returncode}): {proc.stderr.decode(errors='replace').strip()}")
    peak = 0
    for line in Path(status).read_text().splitlines():
        if line.startswith("VmHWM:"):
            peak = int(line.split()[1]) * 1024
    return wall, peak


def has_libigl() -> bool:
    try:
        import igl.embree  # noqa: F401  (submodule, not imported by `import igl`)
    except ImportError:
        return False
    return True


def stage_shares(profile: Path) -> dict[str, float]:
    """Share of the profiled total per stage (cumulative time of the stage's function)."""
    stats = pstats.Stats(str(profile)).stats
    total = max(ct for (_, _, _, ct, _) in stats.values())
    cum: dict[str, float] = {}
    for (file, _, func), (_, _, _, ct, _) in stats.items():
        base = os.path.basename(file)
        for key in (func, f"{func}@{base}", f"{func}@{Path(file).parent.name}"):
            cum[key] = max(cum.get(key, 0.0), ct)
    out = {}
    for stage, names in STAGES:
        for n in names:
            if n in cum:
                out[stage] = cum[n] / total
                break
    return out


class TraceOnly:
    """Bare embreex tracing the rays ``aobake bake --rays N`` casts (prepared beforehand)."""

    def __init__(self, ply: Path):
        from aobake.contacts import contact_origins, ray_offsets
        from aobake.io import load_mesh
        from aobake.tracing import Tracer

        self.surface = load_mesh(ply)
        self.scene = Tracer(self.surface.positions, self.surface.faces)
        self.origins, _ = contact_origins(
            self.surface, self.scene, ray_offsets(self.surface, self.scene.magnitude)
        )

    def runner(self, n_rays: int, threads: int, chunk_rays: int):
        from concurrent.futures import ThreadPoolExecutor

        from aobake.sampling import sample_directions

        dirs = sample_directions(self.surface.normals, n_rays, seed=SEED, measure="cosine")
        per = max(1, chunk_rays // n_rays)
        n = self.surface.n_vertices
        chunks = [
            (np.repeat(self.origins[a : a + per], n_rays, axis=0), dirs[a : a + per].reshape(-1, 3))
            for a in range(0, n, per)
        ]
        del dirs

        def run():
            with ThreadPoolExecutor(max_workers=threads) as pool:
                return sum(int((h != -1).sum()) for h in pool.map(lambda c: self.scene.occluded(*c), chunks))

        return run


def igl_table(ply: Path, codes, repeats: int, out_dir: str, n_vertices: int) -> None:
    """Section 3: libigl's whole process at 64 uniform rays against IGL_ROWS, round-robin."""
    best: dict = {}

    def keep(key, wall, rss):
        if key not in best or wall < best[key][0]:
            best[key] = (wall, max(rss, best.get(key, (0, 0))[1]))

    for _ in range(repeats):
        log("721k libigl 64 uniform rays")
        keep("libigl", *run_libigl(ply, 64, out_dir))
        for label, bake_args in IGL_ROWS:
            for cname, code in codes:
                log(f"721k {label} [{cname}] (against libigl)")
                keep((label, cname), *run_bake(code, ply, bake_args, out_dir))
    igl_wall, igl_rss = best["libigl"]
    rows = [["libigl 64 rays (uniform)", "", f"{igl_wall:.2f} s", "1.00x",
             f"{igl_rss / 2**20:.0f} MiB", f"{igl_rss / n_vertices:.0f}"]]  # fmt: skip
    for label, _ in IGL_ROWS:
        for cname, _ in codes:
            wall, rss = best[(label, cname)]
            rows.append([label, cname, f"{wall:.2f} s", f"{igl_wall / wall:.2f}x (goal >= {IGL_GOAL})",
                         f"{rss / 2**20:.0f} MiB", f"{rss / n_vertices:.0f}"])  # fmt: skip
    C.print_table(
        f"721k: against libigl's whole process (64 uniform rays), load average now {os.getloadavg()[0]:.1f}",
        ["bake", "code", "wall", "libigl wall / wall", "peak RSS", "bytes/vertex"],
        rows,
    )


#: Disjoint stages of :data:`STAGE_MARKS`, in the order of a bake.
STAGE_COLUMNS = ["imports", "read", "normals", "contacts", "scene build", "rays + trace", "write"]


def stage_table(name: str, ply: Path, configs, codes, repeats: int, out_dir: str) -> None:
    """``--stages``: each row's stage wall times (:data:`STAGE_LAUNCH`), round-robin over
    the checkouts, the median of ``repeats`` runs per cell."""
    import json

    runs: dict = {}
    for _ in range(repeats):
        for label, bake_args in configs:
            for cname, code in codes:
                log(f"stage marks {name} {label} [{cname}]")
                path = Path(out_dir) / "marks.json"
                wall, _ = run_bake(code, ply, bake_args, out_dir, marks=path)
                marks = json.loads(path.read_text())
                marks["wall"] = wall
                runs.setdefault((label, cname), []).append(marks)
    rows = []
    for label, _ in configs:
        for cname, _ in codes:
            got = runs[(label, cname)]

            def med(key, got=got):
                return float(np.median([m.get(key, 0.0) for m in got]))

            wall = med("wall")
            known = sum(med(k) for k in STAGE_COLUMNS)
            rows.append([label, cname, f"{wall:.2f} s", f"{med('cpu'):.2f} s", f"{wall - med('process'):.2f}"]
                        + [f"{med(k):.2f}" for k in STAGE_COLUMNS]
                        + [f"{wall - (wall - med('process')) - known:.2f}", f"{med('kernels'):.2f}"])  # fmt: skip
    C.print_table(
        f"{name}: wall seconds per stage (perf_counter marks, median of {repeats}), "
        f"load average now {os.getloadavg()[0]:.1f}",
        ["bake", "code", "wall", "CPU (user + sys)", "interpreter start + end"] + STAGE_COLUMNS + ["other", "of which loading kernels"],
        rows,
        note="imports: the CLI's start to the bake's (numba and embreex load later, in the stages "
        "that first use them); loading kernels: numba loading its cached kernels, inside the stages.",
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--big", action="store_true", help="also the ~3.7M-vertex scene")
    p.add_argument("--huge", action="store_true", help="also the ~27M-vertex scene (this tree's embree "
                   "rows only; needs ~16 GB free)")  # fmt: skip
    p.add_argument("--baseline", type=Path, help="another checkout measured in the same run")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    p.add_argument("--no-profile", action="store_true", help="skip the stage shares")
    p.add_argument("--stages", action="store_true", help="stage wall times from perf_counter "
                   "marks (median of --repeats runs) instead of cProfile's shares")  # fmt: skip
    p.add_argument("--big-rows", default="", help="comma-separated labels: only these rows on "
                   "the larger scenes (e.g. 'embree --rays 1,embree --rays 16')")  # fmt: skip
    p.add_argument("--no-libigl", action="store_true", help="skip the libigl comparison")
    p.add_argument("--only", help="comma-separated parts of the row labels to run (e.g. 'bunnell,rays 16')")
    args = p.parse_args(argv)
    configs = CONFIGS
    if args.only:
        wanted = [w.strip() for w in args.only.split(",") if w.strip()]
        labels = [c[0] for c in CONFIGS]  # a whole label picks its row alone ("rays 1", not 16)
        configs = [c for c in CONFIGS if any(w == c[0] or (w not in labels and w in c[0]) for w in wanted)]
        if not configs:
            p.error(f"--only {args.only!r} matches no row of {[c[0] for c in CONFIGS]}")
    from aobake.constants import CHUNK_RAYS

    here = str(C.ROOT)
    codes = [("this tree", here)]
    if args.baseline is not None:
        codes.append((f"baseline ({args.baseline})", str(args.baseline.resolve())))
    facts = C.machine_facts()
    print("## Whole process: `aobake bake` in a fresh process\n")
    print(C.markdown_table(["", ""], [[k, v] for k, v in facts]))
    print()

    names = ["721k"] + (["3.7M"] if args.big else []) + (["27M"] if args.huge else [])
    with tempfile.TemporaryDirectory() as out_dir:
        log("warming up the numba cache of each checkout")
        warm = scene_file("721k")
        libigl = has_libigl() and not args.no_libigl
        for _, code in codes:
            for _, bake_args in configs + (IGL_ROWS if libigl else []):
                run_bake(code, warm, bake_args, out_dir)
        big_rows = [r.strip() for r in args.big_rows.split(",") if r.strip()]
        for name in names:
            # peaks measured: ~400 B/vertex (embree), ~900 (bunnell, the baseline's embree)
            need = SCENES[name][2] * (600 if name == "27M" else 1200)
            if name != "721k" and mem_available() < need:
                print(f"(skipping the {name} scene: {mem_available() / 2**30:.1f} GiB available, "
                      f"~{need / 2**30:.0f} GiB needed)\n")  # fmt: skip
                continue
            ply = scene_file(name)
            n_vertices = SCENES[name][2]
            trace = None
            if name == "721k":
                log("preparing trace-only rays")
                trace = TraceOnly(ply)
            rows = []
            scene_configs = configs
            if name != "721k" and big_rows:
                scene_configs = [c for c in configs if c[0] in big_rows]
            if name == "27M":  # this tree's embree rows only: the others need more memory
                scene_configs = [c for c in scene_configs if c[0].startswith("embree")]
            for label, bake_args in scene_configs:
                best = {}
                rays = int(bake_args[1]) if bake_args[0] == "--rays" else None
                tr_run = trace.runner(rays, args.threads, CHUNK_RAYS) if trace and rays else None
                scene_codes = codes[:1] if name == "27M" else codes
                for _ in range(1 if name == "27M" else args.repeats):  # minutes per row
                    for cname, code in scene_codes:
                        log(f"{name} {label} [{cname}]")
                        wall, rss = run_bake(code, ply, bake_args, out_dir)
                        if cname not in best or wall < best[cname][0]:
                            best[cname] = (wall, max(rss, best.get(cname, (0, 0))[1]))
                    if tr_run is not None:
                        t = C.timed(tr_run)
                        if "trace" not in best or t.seconds < best["trace"][0]:
                            best["trace"] = (t.seconds, 0)
                del tr_run
                for cname, _ in scene_codes:
                    wall, rss = best[cname]
                    ratio = ""
                    if "trace" in best:
                        goal = GOALS.get(label)
                        r = wall / best["trace"][0]
                        ratio = f"{r:.2f}x" + (f" (goal <= {goal})" if goal else "")
                    rows.append([label, cname, f"{wall:.2f} s",
                                 f"{best['trace'][0]:.2f} s" if "trace" in best else "",
                                 ratio, f"{rss / 2**20:.0f} MiB", f"{rss / n_vertices:.0f}"])  # fmt: skip
            uptime = os.getloadavg()[0]
            C.print_table(
                f"{name} scene ({n_vertices:,} vertices), load average now {uptime:.1f}",
                ["bake", "code", "wall", "embreex trace-only", "wall / trace", "peak RSS", "bytes/vertex"],
                rows,
            )
            if name == "721k" and libigl:
                igl_table(ply, codes, args.repeats, out_dir, n_vertices)
            if args.stages and name == "721k":
                stage_table(name, ply, configs, codes, args.repeats, out_dir)
            elif not args.no_profile and name == "721k":
                prof_rows = []
                for label, bake_args in configs:
                    for cname, code in codes:
                        prof = Path(out_dir) / "run.prof"
                        log(f"profiling {name} {label} [{cname}]")
                        run_bake(code, ply, bake_args, out_dir, profile=prof)
                        shares = stage_shares(prof)
                        rest = 1.0 - sum(shares.values())
                        prof_rows.append([label, cname] + [
                            f"{100 * shares[s]:.0f}%" if s in shares else "" for s, _ in STAGES
                        ] + [f"{100 * rest:.0f}%"])  # fmt: skip
                C.print_table(
                    f"{name}: share of the whole process per stage (cProfile, one run)",
                    ["bake", "code"] + [s for s, _ in STAGES] + ["other (imports, checks, ...)"],
                    prof_rows,
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
