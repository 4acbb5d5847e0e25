"""What every format shares: atomic writes, output-suffix checks, the finite/range guard
run before any write, and one-line messages from text decoding and foreign errors.

Computes nothing; imports numpy and aobake.errors only.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import stat
import sys
import tempfile
import threading
import warnings
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError, NumericalError, OutputError

#: Output suffixes and the writer family that handles them.
BAKE_SUFFIXES = {
    ".ply": "ply",
    ".usda": "usd",
    ".usdc": "usd",
    ".usd": "usd",
    ".usdz": "usdz",
    ".glb": "gltf",
    ".gltf": "gltf",
}


def output_name(path: str | Path) -> str:
    """How a message names an output: its file name, or the whole path when it has none
    (``.``, ``/``); a temporary file of :func:`atomic_write` is named by its output."""
    path = Path(path)
    path = _ACTIVE.get(path, path)
    return path.name or str(path)


def output_kind(path: str | Path) -> str:
    """Return ``"ply"``, ``"usd"``, ``"usdz"`` or ``"gltf"`` for an output path, or raise :class:`FormatError`.

    Called before any computation so a typo in ``-o`` fails fast.
    """
    if not Path(path).name or Path(path).is_dir():
        raise FormatError(f"{output_name(path)}: is a directory; give an output file such as out.ply")
    suffix = Path(path).suffix.lower()
    try:
        return BAKE_SUFFIXES[suffix]
    except KeyError:
        supported = ", ".join(sorted(BAKE_SUFFIXES))
        raise FormatError(
            f"{output_name(path)}: unsupported output suffix {suffix or '(none)'!r}; use one of {supported}"
        ) from None


def check_output_dir(path: str | Path) -> None:
    """Raise :class:`OutputError` if the directory of ``path`` is missing or unwritable."""
    name = output_name(path)
    if not Path(path).name or Path(path).is_dir():
        raise OutputError(f"{name}: output path is a directory")
    parent = Path(path).resolve().parent
    if not parent.is_dir():
        raise OutputError(f"{name}: output directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise OutputError(f"{name}: output directory {parent} is not writable")


def check_not_input(output: str | Path, inputs) -> None:
    """Raise :class:`OutputError` when ``output`` is one of ``inputs`` (the same file,
    through any path): a command never writes over what it reads."""
    out = Path(output)
    for item in inputs:
        if not isinstance(item, (str, os.PathLike)):
            continue  # an in-memory mesh
        with contextlib.suppress(OSError):
            if out.exists() and os.path.samefile(out, item):
                raise OutputError(f"{output_name(out)}: is also an input; refusing to write over it")


#: What a path that exists but is no regular file is, for the message.
_NOT_REGULAR = (
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def check_input_file(path: str | Path, what: str = "mesh file") -> Path:
    """Return ``path`` if it names a regular file (symlinks followed), else raise the
    one-line :class:`InputError`: missing, a directory, or a FIFO, device or socket.

    Checked before any read: a FIFO blocks the reader and ``/dev/zero`` never ends.
    """
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise InputError(path, "file not found") from None
    except OSError as exc:
        raise InputError(path, f"cannot read file: {exc.strerror or exc}") from None
    if stat.S_ISDIR(mode):
        raise InputError(path, f"is a directory, not a {what}")
    if not stat.S_ISREG(mode):
        kind = next((name for test, name in _NOT_REGULAR if test(mode)), "not a regular file")
        raise InputError(path, f"is {kind}, not a {what}; give a regular file")
    return path


def check_ao(
    ao: np.ndarray, name: str = "ao", *, n_vertices: int | None = None, where: str = ""
) -> np.ndarray:
    """Return ``ao`` as float32 after checking it is finite and within [0, 1].

    Parameters
    ----------
    ao : array_like
    name : str
        What the finite/range messages start with.
    n_vertices : int, optional
        When given, ``ao`` must also have shape ``(n_vertices,)``.
    where : str
        What the shape message starts with (the output file's name).

    Raises
    ------
    NumericalError
        A non-finite value, a value outside [0, 1], or the wrong shape: NaN or inf never
        reaches a file.
    """
    ao = np.asarray(ao)
    bad = ~np.isfinite(ao)
    if bad.any():
        raise NumericalError(f"{name}: {int(bad.sum())} non-finite values; refusing to write")
    if ao.size and (ao.min() < 0.0 or ao.max() > 1.0):
        raise NumericalError(
            f"{name}: values outside [0, 1] (min {ao.min():.6g}, max {ao.max():.6g}); refusing to write"
        )
    if n_vertices is not None and ao.shape != (n_vertices,):
        raise NumericalError(
            f"{where or name}: ao has shape {ao.shape} but the mesh has {n_vertices} vertices"
        )
    return ao.astype(np.float32)


#: Kinds of extra per-vertex attributes, by name: ``bentNormal`` is a normal, names
#: starting ``irradiance`` are linear colours; any other name is a float per vertex.
NORMAL_ATTRIBUTES = ("bentNormal",)
COLOR_PREFIX = "irradiance"

#: Names an extra attribute may not take: what the writers already author.
RESERVED_ATTRIBUTES = frozenset(
    {"ao", "quality", "x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "alpha",
     "displayColor", "displayOpacity", "normals", "points", "st"}
)  # fmt: skip


def attribute_kind(name: str) -> str:
    """``"normal"``, ``"color"`` or ``"float"``: how an extra attribute is written
    (USD ``normal3f[]``/``color3f[]``/``float[]``; PLY ``name_x``/``name_r``/``name``)."""
    if name in NORMAL_ATTRIBUTES:
        return "normal"
    if name.startswith(COLOR_PREFIX):
        return "color"
    return "float"


def check_attributes(
    attributes: Mapping[str, np.ndarray] | None, n_vertices: int, where: str
) -> dict[str, tuple[str, np.ndarray]]:
    """Extra per-vertex attributes checked and ready to write: name -> (kind, float32).

    A name is an identifier (letters, digits, ``_``; not starting with a digit), not one
    the writers author themselves (``ao``, ``displayColor``...). Normals and colours are
    ``(n, 3)``, floats ``(n,)``; every value finite, colours non-negative.

    Raises
    ------
    NumericalError
        A bad name, shape or value (checked before any file is opened).
    """
    out: dict[str, tuple[str, np.ndarray]] = {}
    for name, values in (attributes or {}).items():
        if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
            raise NumericalError(f"{where}: attribute name {name!r} is not an identifier")
        if name in RESERVED_ATTRIBUTES:
            raise NumericalError(f"{where}: attribute name {name!r} is already written by aobake")
        kind = attribute_kind(name)
        values = np.asarray(values)
        shape = (n_vertices,) if kind == "float" else (n_vertices, 3)
        if values.shape != shape or not np.issubdtype(values.dtype, np.number):
            raise NumericalError(
                f"{where}: attribute {name!r} has shape {values.shape}; a {kind} attribute "
                f"needs {shape} numbers"
            )
        bad = ~np.isfinite(values)
        if bad.any():
            raise NumericalError(f"{name}: {int(bad.sum())} non-finite values; refusing to write")
        if kind == "color" and values.size and values.min() < 0:
            raise NumericalError(f"{name}: negative colour values (min {values.min():.6g}); refusing to write")
        out[name] = (kind, np.ascontiguousarray(values, dtype=np.float32))
    return out


def check_display(display, n_vertices: int, where: str) -> np.ndarray | None:
    """The ``(n, 3)`` linear RGB that ``--color`` writes instead of grey ``ao``, as
    float32, or None; finite and within [0, 1] (raises :class:`NumericalError`)."""
    if display is None:
        return None
    display = np.asarray(display)
    if display.shape != (n_vertices, 3):
        raise NumericalError(
            f"{where}: display colours have shape {display.shape}; expected ({n_vertices}, 3)"
        )
    check_ao(display, "display colours")
    return np.ascontiguousarray(display, dtype=np.float32)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


#: Temporary files of the atomic writes under way -> their outputs (a writer called on a
#: temporary file writes into it instead of nesting another one; messages name the output).
_ACTIVE: dict[Path, Path] = {}

#: Signals held back while a temporary file is created or removed, so a Ctrl-C or a
#: SIGTERM cannot leave one behind between its creation and the cleanup handler.
_HELD = (signal.SIGINT, signal.SIGTERM)

#: Longest file name most file systems take (bytes).
_NAME_MAX = 255

#: Bytes left over for USD, which saves through a temporary sibling of its own
#: (``<name>.XXXXXX``, TfSafeOutputFile).
_FOREIGN_MARGIN = 8


def _temporary_prefix(path: Path) -> str:
    """``.<stem>.`` cut so the temporary name (prefix, 8 random characters, suffix) and
    USD's own temporary sibling of it stay within 255 bytes (a long output name
    otherwise fails only for its temporary sibling)."""
    budget = _NAME_MAX - _FOREIGN_MARGIN - len(os.fsencode(path.suffix)) - 8 - 2
    stem = os.fsencode(path.stem)[: max(budget, 0)]
    return "." + os.fsdecode(stem) + "."


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """Hold Ctrl-C and SIGTERM back for the body, then deliver what came (the Python
    handlers are swapped, so this works whichever thread the OS signalled)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: list[int] = []
    previous = {sig: signal.signal(sig, lambda signum, frame: came.append(signum)) for sig in _HELD}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        for sig in dict.fromkeys(came):
            signal.raise_signal(sig)


def _cannot_write(path: Path, exc: OSError) -> OutputError:
    return OutputError(f"{output_name(path)}: cannot write ({exc.strerror or short_reason(exc)})")


@contextlib.contextmanager
def atomic_write(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it over ``path`` on success.

    The temporary name keeps the suffix (USD picks its format from it). On any exception,
    including KeyboardInterrupt and SIGTERM (the CLI raises it as an interrupt), the
    temporary file is removed and nothing is left behind. An :class:`OSError` (disk
    full, read-only or vanished directory, name too long) becomes one
    :class:`OutputError` naming ``path``. Called on a temporary file of an atomic write
    under way, it yields that file (the outer write renames it).
    """
    path = Path(path)
    if path in _ACTIVE:
        yield path
        return
    check_output_dir(path)
    tmp = None
    try:
        with _signals_held():  # a signal held here is raised inside this try: cleaned up
            fd, tmp_name = tempfile.mkstemp(
                prefix=_temporary_prefix(path), suffix=path.suffix, dir=path.resolve().parent
            )
            tmp = Path(tmp_name)
            _ACTIVE[tmp] = path
            os.close(fd)
        yield tmp
        # mkstemp creates 0600; give the output the mode a plain open() would have.
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except OSError as exc:
        _discard(tmp)
        raise _cannot_write(path, exc) from None
    except BaseException:
        _discard(tmp)
        raise
    finally:
        _ACTIVE.pop(tmp, None)


def _discard(tmp: Path | None) -> None:
    if tmp is not None:
        with _signals_held(), contextlib.suppress(OSError):
            tmp.unlink()


@contextlib.contextmanager
def foreign_stderr(name: str) -> Iterator[None]:
    """Run a foreign library's C++ code (USD) with file descriptor 2 going to a temporary
    file. What it printed comes back as Python warnings (``name: text``, a line each) when
    the body succeeds, which the CLI shows only if the command succeeds; on failure it is
    dropped, the one-line error says what failed."""
    sys.stderr.flush()
    with tempfile.TemporaryFile() as buf:
        saved = os.dup(2)
        os.dup2(buf.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        buf.seek(0)
        text = buf.read().decode("utf-8", "replace")
    for line in text.splitlines():
        # USD's "Warning: in Func at line N of file.cpp -- text": keep the text
        line = re.sub(r"^\s*(Warning|Runtime Error|Coding Error|Error):\s*", "", line)
        line = " ".join(re.sub(r"^in \S+ at line \d+ of \S+ -- ", "", line).split())
        if line:
            warnings.warn(f"{name}: {line}", RuntimeWarning, stacklevel=3)


#: Longest foreign error text kept in a one-line message.
_REASON_CHARS = 160


def short_reason(exc: BaseException) -> str:
    """A foreign exception's message on one short line (USD's Tf errors reduced to their text)."""
    text = str(exc)
    tf_messages = re.findall(
        r"Error in '[^']*' at line \d+ in file [^:]* : '(.*?)'(?=\s*(?:Error in|$))", text, re.S
    )
    if tf_messages:
        text = tf_messages[0]
    text = " ".join(text.split()) or type(exc).__name__
    if len(text) > _REASON_CHARS:
        text = text[: _REASON_CHARS - 3] + "..."
    return text


def decode_text(
    path: Path, data: bytes, fmt: str, problem: str = "binary data, not a text file"
) -> str:
    """Text of a text format, or :class:`InputError` when the bytes are binary."""
    problem = f"cannot read as {fmt}: {problem}"
    if b"\x00" in data:
        raise InputError(path, problem)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = data.decode("latin-1")  # legacy exporters write latin-1 names and comments
    if re.search(r"[\x01-\x08\x0e-\x1f\x7f]", text):
        raise InputError(path, problem)
    return text
