"""``aobake batch``: bake many inputs on a Dask cluster (a local one by default), resumable.

The only module that imports dask/distributed, inside the functions that need them.
Plans the jobs (inputs -> ``OUTDIR/<relative path>/<stem>.<ext>``), skips what the
manifest records as up to date, runs the rest as Dask tasks (one per input, or K vertex
ranges plus a stitching task with ``split``), and records every input in
``OUTDIR/manifest.json`` and ``manifest.csv``. Outputs are written atomically by
:func:`aobake.pipeline.bake_file` / :func:`~aobake.pipeline.write_parts` on the workers.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import fcntl
import glob
import hashlib
import io
import json
import logging
import os
import re
import shlex
import signal
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from . import __version__
from .errors import AobakeError, InputError, OutputError

MANIFEST = "manifest.json"
MANIFEST_CSV = "manifest.csv"
LOCK = ".aobake-batch.lock"
#: Text files listing inputs, one path (or pattern, or directory) a line.
LIST_SUFFIXES = (".txt", ".lst")
CSV_COLUMNS = (
    "input", "status", "error", "vertices", "method", "rays", "seconds", "worker",
    "outputs", "output_hashes", "input_hash", "options_key", "version", "source",
)  # fmt: skip


@dataclass(frozen=True)
class Job:
    """One input and the files it becomes.

    Attributes
    ----------
    key : str
        Its relative path (POSIX), the manifest's key.
    source : str
        Absolute input path.
    outputs : tuple of str
        Absolute output paths, one per format.
    """

    key: str
    source: str
    outputs: tuple


@dataclass(frozen=True)
class Settings:
    """What every bake of a batch uses: the arguments of :func:`aobake.pipeline.bake_file`."""

    method: str = "embree"
    options: dict = field(default_factory=dict)
    color: bool = False
    up_axis: str | None = None
    meters_per_unit: float | None = None
    fields: tuple = ()
    channel: str | None = None
    weld: bool = False
    time: float | None = None
    overlay: bool | None = None
    receivers: tuple = ()
    occluders: tuple = ()
    effects: str | tuple = "auto"
    lights: tuple = ()
    scene_lights: bool = True
    split_irradiance: bool = False
    exposure: float = 0.0
    ground: str | float | None = None

    def bake_kwargs(self, threads: int | None) -> dict:
        options = dict(self.options)
        if threads is not None and options.get("threads") is None and _takes_threads(self.method):
            options["threads"] = threads
        return dict(
            method=self.method,
            color=self.color,
            up_axis=self.up_axis,
            meters_per_unit=self.meters_per_unit,
            fields=self.fields,
            channel=self.channel,
            weld=self.weld,
            time=self.time,
            overlay=self.overlay,
            receivers=self.receivers,
            occluders=self.occluders,
            effects=self.effects,
            lights=self.lights,
            scene_lights=self.scene_lights,
            split_irradiance=self.split_irradiance,
            exposure=self.exposure,
            ground=self.ground,
            **options,
        )


@dataclass
class BatchResult:
    """What a batch did: the manifest's records of this run's inputs, and counts."""

    records: list
    done: int = 0
    skipped: int = 0
    failed: int = 0
    seconds: float = 0.0
    manifest: str = ""

    def summary(self) -> str:
        n = len(self.records)
        text = f"batch: {n} input{'s' if n != 1 else ''}: {self.done} baked, {self.skipped} up to date"
        text += f", {self.failed} failed" if self.failed else ""
        return text + f" in {self.seconds:.2f} s -> {self.manifest}"


# --------------------------------------------------------------------------------------
# planning


def _mesh_suffixes() -> dict:
    from .io import INPUT_FORMATS

    return INPUT_FORMATS


def find_inputs(paths: Sequence[str | Path], exclude: Path | None = None) -> list[tuple[Path, Path]]:
    """``[(source, relative path)]`` of every mesh that ``paths`` name, in order, once each.

    A path is a mesh file (relative path: its name), a directory (its meshes, searched
    recursively, relative to it; hidden files skipped), a ``.txt``/``.lst`` file listing
    such paths one a line (relative to the list; ``#`` starts a comment) or a glob pattern
    (``**`` recurses). Files that directories, lists and patterns find under ``exclude``
    (the output directory) are skipped.
    """
    suffixes = _mesh_suffixes()
    found: dict[Path, Path] = {}
    exclude = None if exclude is None else exclude.resolve()

    def excluded(path: Path) -> bool:
        return exclude is not None and path.resolve().is_relative_to(exclude)

    def add(path: Path, base: Path | None, depth: int) -> None:
        if path.is_dir():
            for p in sorted(path.rglob("*")):
                rel = p.relative_to(path)
                if p.is_file() and p.suffix.lower() in suffixes and not any(s.startswith(".") for s in rel.parts):
                    if not excluded(p):
                        found.setdefault(p.resolve(), rel)
            return
        if path.is_file():
            suffix = path.suffix.lower()
            if suffix in suffixes:  # named: kept even inside OUTDIR (plan() refuses overwrites)
                if depth == 0 or not excluded(path):
                    found.setdefault(path.resolve(), Path(path.name))
                return
            if suffix in LIST_SUFFIXES and depth == 0:
                for line in path.read_text(errors="replace").splitlines():
                    line = line.split("#", 1)[0].strip()
                    if line:
                        entry = Path(line) if Path(line).is_absolute() else path.parent / line
                        add(entry, None, depth + 1)
                return
            raise InputError(path, f"not a mesh file ({', '.join(sorted(suffixes))}) nor a list of paths (.txt, .lst)")
        if glob.has_magic(str(path)):
            matches = sorted(glob.glob(str(path), recursive=True))
            if not matches:
                raise InputError(path, "no file matches this pattern")
            for m in matches:
                if Path(m).is_dir() or Path(m).suffix.lower() in suffixes:
                    add(Path(m), None, depth + 1)
            return
        raise InputError(path, "file not found")

    for p in paths:
        add(Path(p), None, 0)
    return list(found.items())


def plan(inputs: list[tuple[Path, Path]], outdir: Path, formats: Sequence[str]) -> list[Job]:
    """One :class:`Job` per input; names that collide (two inputs, one output; an output
    that is an input) are refused before any work, in one line."""
    outdir = Path(outdir).resolve()
    jobs, owner = [], {}
    sources = {str(src) for src, _ in inputs}
    for src, rel in inputs:
        outputs = tuple(str(outdir / rel.parent / f"{rel.stem}.{ext}") for ext in formats)
        for out in outputs:
            if out in owner:
                raise OutputError(
                    f"{Path(out).relative_to(outdir)}: both {owner[out]} and {src} would be baked into it; "
                    "rename one or bake them in separate batches"
                )
            if out in sources:
                raise OutputError(f"{out}: an output would overwrite an input; choose another output directory")
            owner[out] = src
        jobs.append(Job(key=rel.as_posix(), source=str(src), outputs=outputs))
    return jobs


def file_hash(path: str | Path) -> str:
    """sha256 of a file's bytes (hex)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _light_key(settings: Settings) -> dict:
    """The light settings that differ from their defaults (an AO batch's key is unchanged)."""
    defaults = Settings()
    names = ("effects", "lights", "scene_lights", "split_irradiance", "exposure")
    return {
        name: list(value) if isinstance(value, tuple) else value
        for name in names
        if (value := getattr(settings, name)) != getattr(defaults, name)
    }


def settings_key(settings: Settings, formats: Sequence[str]) -> tuple[dict, str]:
    """What decides the outputs' bytes besides the input (every option resolved to its
    value, field files by content, the formats), and its sha256."""
    from .methods import make_options

    opts = dataclasses.asdict(make_options(settings.method, settings.options))
    opts.pop("threads", None)  # never changes a result
    described = {
        "method": settings.method,
        "options": opts,
        "color": settings.color,
        "up_axis": settings.up_axis,
        "meters_per_unit": settings.meters_per_unit,
        "channel": settings.channel,
        "weld": settings.weld,
        "time": settings.time,
        "overlay": settings.overlay,
        **{key: list(getattr(settings, key)) for key in ("receivers", "occluders") if getattr(settings, key)},
        **_light_key(settings),
        "fields": [
            {"file": Path(f).name, "sha256": file_hash(f), "placement": None if p is None else list(p)}
            for f, p in (_field_parts(item) for item in settings.fields)
        ],
        "formats": list(formats),
    }
    if settings.ground is not None:  # only when given: earlier manifests keep their keys
        described["ground"] = settings.ground
    text = json.dumps(described, sort_keys=True, default=str)
    return described, hashlib.sha256(text.encode()).hexdigest()


def _field_parts(item) -> tuple[Path, Any]:
    if isinstance(item, tuple):
        return Path(item[0]), item[1]
    return Path(item), None


def up_to_date(record: dict | None, input_hash: str, key: str, outdir: Path) -> bool:
    """Whether the manifest's ``record`` says this input was baked from the same bytes,
    options and aobake version, and every output it wrote is still there unchanged."""
    if not record or record.get("status") not in ("done", "skipped"):
        return False
    if record.get("input_hash") != input_hash or record.get("options_key") != key:
        return False
    if record.get("version") != __version__:
        return False
    hashes = record.get("output_hashes") or {}
    if not hashes:
        return False
    for name, digest in hashes.items():
        path = outdir / name
        if not path.is_file() or file_hash(path) != digest:
            return False
    return True


def load_manifest(outdir: Path) -> dict:
    """The manifest's records by input key ({} when there is none or it is unreadable)."""
    path = Path(outdir) / MANIFEST
    try:
        data = json.loads(path.read_text())
        return {r["input"]: r for r in data.get("inputs", []) if isinstance(r, dict) and "input" in r}
    except (OSError, ValueError, AttributeError, TypeError, KeyError):
        return {}


def write_manifest(outdir: Path, records: dict, described: dict) -> None:
    """``manifest.json`` and ``manifest.csv``, each written atomically."""
    from .io import atomic_write

    rows = [records[k] for k in sorted(records)]
    data = {"aobake": __version__, "settings": described, "inputs": rows}
    with atomic_write(outdir / MANIFEST) as tmp:
        tmp.write_text(json.dumps(data, indent=1, sort_keys=True, default=str) + "\n")
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=CSV_COLUMNS, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for r in rows:
        flat = dict(r)
        flat["outputs"] = " ".join(r.get("outputs") or [])
        flat["output_hashes"] = " ".join((r.get("output_hashes") or {}).values())
        writer.writerow(flat)
    with atomic_write(outdir / MANIFEST_CSV) as tmp:
        tmp.write_text(buf.getvalue())


@contextlib.contextmanager
def outdir_lock(outdir: Path):
    """Hold ``OUTDIR/.aobake-batch.lock`` (an flock, released when the process ends, even
    killed); a second batch on the same directory is refused in one line."""
    path = Path(outdir) / LOCK
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            other = os.pread(fd, 64, 0).decode(errors="replace").strip() or "?"
            raise OutputError(f"{outdir}: another aobake batch (pid {other}) is writing here; wait for it to end") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield
    finally:
        os.close(fd)


def _temp_pattern(output: str) -> re.Pattern:
    """The temporary names :func:`aobake.io.atomic_write` uses for ``output``."""
    p = Path(output)
    return re.compile(rf"^\.{re.escape(p.stem)}\.[a-z0-9_]{{8}}{re.escape(p.suffix)}$")


def remove_stale_temporaries(jobs: Sequence[Job]) -> int:
    """Remove temporary files of our outputs left by a worker killed while it wrote (an
    exception removes its own); only run while holding the OUTDIR lock."""
    removed = 0
    for job in jobs:
        for out in job.outputs:
            parent, pattern = Path(out).parent, _temp_pattern(out)
            for p in parent.glob(f".{glob.escape(Path(out).stem)}.*"):
                if pattern.match(p.name):
                    with contextlib.suppress(OSError):
                        p.unlink()
                        removed += 1
    return removed


# --------------------------------------------------------------------------------------
# tasks (run on the workers)


@dataclass(frozen=True)
class _Failure:
    """An input that cannot be baked (an AobakeError: retrying cannot help)."""

    error: str


def _worker_threads(slots: dict) -> int | None:
    """Bake threads for a task on this worker: the host's cores shared among the task
    slots of all workers on it, so concurrent bakes do not oversubscribe the cores."""
    try:
        from distributed import get_worker

        worker = get_worker()
    except (ImportError, ValueError):
        return None
    host = worker.address.rsplit(":", 1)[0]
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, cores // max(1, slots.get(host, worker.state.nthreads)))


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return "local"


def _record(report, job: Job, outdir: str) -> dict:
    return {
        "status": "done",
        "error": "",
        "vertices": report.n_vertices,
        "method": report.method,
        "rays": report.n_rays,
        "seconds": round(report.seconds, 6),
        "worker": _worker_name(),
        "output_hashes": {os.path.relpath(o, outdir): file_hash(o) for o in job.outputs},
    }


def bake_task(job: Job, settings: Settings, slots: dict, outdir: str) -> dict:
    """Bake one input into its outputs; a bad input gives a failed record (no retry)."""
    from .pipeline import bake_file

    try:
        report = bake_file(job.source, job.outputs, **settings.bake_kwargs(_worker_threads(slots)))
    except AobakeError as exc:
        return {"status": "failed", "error": str(exc), "worker": _worker_name()}
    return _record(report, job, outdir)


def part_task(job: Job, settings: Settings, part: tuple, slots: dict):
    """Vertex range ``part = (k, K)`` of one input: ``(PartResult, surface or None)``, or a
    _Failure. The first range also returns the loaded mesh: the stitching task then runs
    on its worker (Dask places a task by the bytes of its inputs) and does not read the
    file again."""
    from .io import load_mesh
    from .pipeline import bake_part

    kw = settings.bake_kwargs(_worker_threads(slots))
    for name in ("color", "meters_per_unit", "fields", "channel", "weld", "overlay", "split_irradiance", "exposure"):
        kw.pop(name)  # up_axis and ground stay: the plane is resolved along the up axis
    try:
        surface = load_mesh(job.source, time=kw.pop("time"))
        return bake_part(surface, parts=part, **kw), surface if part[0] == 0 else None
    except AobakeError as exc:
        return _Failure(str(exc))


def write_task(job: Job, settings: Settings, outdir: str, *parts) -> dict:
    """Stitch the ranges of one input and write its outputs."""
    from .pipeline import write_parts

    failed = [p for p in parts if isinstance(p, _Failure)]
    if failed:
        return {"status": "failed", "error": failed[0].error, "worker": _worker_name()}
    surface = parts[0][1]
    try:
        kw = settings.bake_kwargs(None)
        kw.pop("weld")  # --split refuses --weld: ranges are of the input's vertices
        report = write_parts(job.source, job.outputs, [p for p, _ in parts], surface=surface, **kw)
    except AobakeError as exc:
        return {"status": "failed", "error": str(exc), "worker": _worker_name()}
    return _record(report, job, outdir)


# --------------------------------------------------------------------------------------
# the run


def _takes_threads(method: str) -> bool:
    from .methods import options_class
    from .options import specs

    return "threads" in specs(options_class(method))


def pending_jobs(jobs, outdir, settings, formats, force) -> tuple[list, dict, dict, str, dict]:
    """The jobs to bake, the old records, input hashes, the settings key and description."""
    described, key = settings_key(settings, formats)
    old = load_manifest(outdir)
    hashes, pending = {}, []
    for job in jobs:
        try:
            hashes[job.key] = file_hash(job.source)
        except OSError as exc:
            raise InputError(job.source, f"cannot read file: {exc.strerror}") from None
        if force or not up_to_date(old.get(job.key), hashes[job.key], key, outdir):
            pending.append(job)
    return pending, old, hashes, key, described


def _error_line(exc: BaseException) -> str:
    from .io.common import short_reason

    name = type(exc).__name__
    if name == "KilledWorker":
        return "the worker baking it died, also on every retry (out of memory? killed?)"
    if name == "CancelledError":
        return "cancelled"
    return f"{name}: {short_reason(exc)}"


def _start_client(scheduler: str | None, workers: int | None, retries: int):
    """A distributed Client: on ``scheduler``, or on a new LocalCluster of ``workers``
    single-threaded worker processes (their bakes share the cores: :func:`_worker_threads`)."""
    import dask
    from distributed import Client, LocalCluster

    for name in ("distributed", "tornado", "bokeh"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
    if scheduler is not None:
        try:
            return Client(scheduler, timeout="15s"), None
        except (OSError, TimeoutError) as exc:
            raise OutputError(f"{scheduler}: cannot connect to the Dask scheduler ({exc})") from None
    if workers is None:
        workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    # A worker process that dies while baking (killed, out of memory) is restarted by its
    # nanny and the task rerun, up to `retries` times.
    # Ctrl-C goes to the whole process group: the workers ignore it (inherited) and this
    # process cancels their tasks instead, so nothing is killed mid-write.
    previous = signal.getsignal(signal.SIGINT) if _main_thread() else None
    if previous is not None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with dask.config.set({"distributed.scheduler.allowed-failures": max(0, retries)}):
            cluster = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address="127.0.0.1:0",
                silence_logs=logging.CRITICAL,
            )
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    return Client(cluster), cluster


def _main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def _slots(client) -> dict:
    """Task slots (worker threads) per host of the cluster."""
    slots: dict = {}
    for address, info in client.scheduler_info().get("workers", {}).items():
        host = address.rsplit(":", 1)[0]
        slots[host] = slots.get(host, 0) + int(info.get("nthreads", 1))
    return slots


def run_batch(
    paths: Sequence[str | Path],
    outdir: str | Path,
    *,
    formats: Sequence[str] = ("ply", "usda"),
    settings: Settings | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    client=None,
    split: int = 1,
    retries: int = 2,
    force: bool = False,
    bar=None,
    on_failure=None,
) -> BatchResult:
    """Bake every input ``paths`` name into ``outdir``; see the module docstring.

    ``client``: an existing ``distributed.Client`` to use (else one on ``scheduler`` or
    a new LocalCluster of ``workers`` processes). ``bar``: a
    :class:`aobake.progress.BatchBar`-like object. ``on_failure(record)`` is called per
    failed input as it fails. Returns a :class:`BatchResult`; raises AobakeError for
    problems found before any work (bad paths, colliding names, a locked OUTDIR).
    """
    from .progress import NullBatchBar

    t0 = time.perf_counter()
    settings = settings or Settings()
    bar = bar or NullBatchBar()
    outdir = Path(outdir)
    jobs = _prepare(paths, outdir, formats, settings, split)
    outdir.mkdir(parents=True, exist_ok=True)
    with outdir_lock(outdir):
        remove_stale_temporaries(jobs)
        pending, old, hashes, key, described = pending_jobs(jobs, outdir, settings, formats, force)
        records = dict(old)
        result = BatchResult(records=[], manifest=str(outdir / MANIFEST))
        waiting = {job.key for job in pending}
        for job in jobs:
            if job.key not in waiting:
                records[job.key] = {**old[job.key], "status": "skipped"}
                result.skipped += 1
        bar.start(len(jobs))
        bar.update(result.done, result.failed, result.skipped)
        try:
            if pending:
                _run(pending, outdir, settings, split, retries, client, scheduler, workers, records,
                     hashes, key, described, result, bar, on_failure)  # fmt: skip
        finally:
            bar.finish()
            remove_stale_temporaries(jobs)
            write_manifest(outdir, records, described)
        result.records = [records[job.key] for job in jobs]
        result.seconds = time.perf_counter() - t0
        return result


def _prepare(paths, outdir: Path, formats, settings: Settings, split: int) -> list[Job]:
    from .io import output_kind

    if split > 1:
        from .methods import SPLITTABLE

        if settings.method not in SPLITTABLE:
            raise ValueError(f"--split applies to {', '.join(SPLITTABLE)} only: {settings.method} couples all vertices")
    for ext in formats:
        output_kind(f"x.{ext}")
    for item in settings.fields:
        f, _ = _field_parts(item)
        if not f.is_file():
            raise InputError(f, "file not found")
    if outdir.exists() and not outdir.is_dir():
        raise OutputError(f"{outdir}: exists and is not a directory")
    jobs = plan(find_inputs(paths, exclude=outdir), outdir, formats)
    if not jobs:
        raise AobakeError("no mesh files found in " + " ".join(str(p) for p in paths))
    return jobs


def _run(pending, outdir, settings, split, retries, client, scheduler, workers, records,
         hashes, key, described, result, bar, on_failure) -> None:  # fmt: skip
    from distributed import as_completed

    own_client, cluster = (None, None) if client is not None else _start_client(scheduler, workers, retries)
    client = client or own_client
    futures = {}
    last_write = time.perf_counter()
    try:
        # parent directories of the outputs (the write check needs them)
        for job in pending:
            for out in job.outputs:
                Path(out).parent.mkdir(parents=True, exist_ok=True)
        slots = _slots(client)
        for job in pending:
            if split > 1:
                parts = [
                    client.submit(part_task, job, settings, (k, split), slots, retries=retries, pure=False)
                    for k in range(split)
                ]
                final = client.submit(write_task, job, settings, str(outdir), *parts, retries=retries, pure=False)
            else:
                final = client.submit(bake_task, job, settings, slots, str(outdir), retries=retries, pure=False)
            futures[final] = job
        def record(future) -> None:
            job = futures.pop(future)
            try:
                rec = future.result()
            except Exception as exc:  # retries used up, worker lost, cancelled
                rec = {"status": "failed", "error": _error_line(exc), "worker": ""}
            rec.update(
                input=job.key,
                source=job.source,
                outputs=[os.path.relpath(o, outdir) for o in job.outputs],
                input_hash=hashes[job.key],
                options_key=key,
                version=__version__,
            )
            rec.setdefault("method", settings.method)
            records[job.key] = rec
            if rec["status"] == "failed":
                result.failed += 1
                if on_failure is not None:
                    on_failure(rec)
            else:
                result.done += 1
            bar.update(result.done, result.failed, result.skipped)

        try:
            for future in as_completed(list(futures)):
                record(future)
                if time.perf_counter() - last_write > 5.0:  # a killed client loses little
                    write_manifest(outdir, records, described)
                    last_write = time.perf_counter()
        except KeyboardInterrupt:  # keep what has finished; the rest is cancelled below
            for future in [f for f in futures if f.status == "finished"]:
                record(future)
            raise
    finally:
        # interrupted: drop what has not run (running tasks end atomically); each step
        # on its own, as the cluster may be gone already
        steps = [lambda: client.cancel(list(futures), force=True)] if futures else []
        steps += [c.close for c in (own_client, cluster) if c is not None]
        for step in steps:
            with contextlib.suppress(Exception):
                step()


def bake_arguments(settings: Settings) -> list[str]:
    """The ``aobake bake`` options that reproduce ``settings`` (those set explicitly)."""
    from .methods import options_class
    from .options import flag, specs

    args = ["--method", settings.method]
    fields = specs(options_class(settings.method))
    for name, value in settings.options.items():
        if value is None or name not in fields:
            continue
        spec = fields[name][0]
        if spec.kind is bool:
            args.append(flag(name, spec) if value else "--no-" + flag(name, spec)[2:])
        else:
            args += [flag(name, spec), str(value)]
    if settings.color:
        args.append("--color")
    if settings.channel:
        args += ["--channel", settings.channel]
    if settings.weld:
        args.append("--weld")
    if settings.time is not None:
        args += ["--time", repr(settings.time)]
    if settings.overlay is not None:
        args.append("--overlay" if settings.overlay else "--no-overlay")
    for key in ("receivers", "occluders"):
        for pattern in getattr(settings, key):
            args += [f"--{key}", pattern]
    if settings.up_axis:
        args += ["--up", settings.up_axis]
    if settings.ground is not None:
        args += ["--ground", settings.ground if settings.ground == "auto" else repr(float(settings.ground))]
    if settings.meters_per_unit:
        args += ["--meters-per-unit", repr(settings.meters_per_unit)]
    for item in settings.fields:
        f, placement = _field_parts(item)
        args += ["--field", str(f) + ("" if placement is None else "@" + ",".join(repr(float(v)) for v in placement))]
    return args


def emit_commands(
    paths: Sequence[str | Path],
    outdir: str | Path,
    *,
    formats: Sequence[str] = ("ply", "usda"),
    settings: Settings | None = None,
    force: bool = False,
) -> list[str]:
    """One ``aobake bake SRC -o OUT ...`` shell line per input that is not up to date
    (output directories are created, so each line runs as it is)."""
    settings = settings or Settings()
    outdir = Path(outdir)
    jobs = _prepare(paths, outdir, formats, settings, 1)
    pending, *_ = pending_jobs(jobs, outdir, settings, formats, force)
    common = bake_arguments(settings)
    lines = []
    for job in pending:
        args = ["aobake", "bake", job.source]
        for out in job.outputs:
            Path(out).parent.mkdir(parents=True, exist_ok=True)
            args += ["-o", out]
        lines.append(shlex.join(args + common))
    return lines
