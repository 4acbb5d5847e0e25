"""What every format shares: atomic writes, output-suffix checks, the finite/range guard
run before any write, and one-line messages from text decoding and foreign errors.

Computes nothing; imports numpy and aobake.errors only.
"""

from __future__ import annotations

import contextlib
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError, NumericalError, OutputError

#: Output suffixes and the writer family that handles them.
BAKE_SUFFIXES = {".ply": "ply", ".usda": "usd", ".usdc": "usd", ".usd": "usd", ".usdz": "usdz"}


def output_kind(path: str | Path) -> str:
    """Return ``"ply"``, ``"usd"`` or ``"usdz"`` for an output path, or raise :class:`FormatError`.

    Called before any computation so a typo in ``-o`` fails fast.
    """
    suffix = Path(path).suffix.lower()
    try:
        return BAKE_SUFFIXES[suffix]
    except KeyError:
        supported = ", ".join(sorted(BAKE_SUFFIXES))
        raise FormatError(
            f"{Path(path).name}: unsupported output suffix {suffix or '(none)'!r}; use one of {supported}"
        ) from None


def check_output_dir(path: str | Path) -> None:
    """Raise :class:`OutputError` if the directory of ``path`` is missing or unwritable."""
    parent = Path(path).resolve().parent
    if not parent.is_dir():
        raise OutputError(f"{Path(path).name}: output directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise OutputError(f"{Path(path).name}: output directory {parent} is not writable")
    if Path(path).is_dir():
        raise OutputError(f"{Path(path).name}: output path is a directory")


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


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_write(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it over ``path`` on success.

    The temporary name keeps the suffix (USD picks its format from it). On any exception,
    including KeyboardInterrupt, the temporary file is removed and nothing is left behind.
    """
    path = Path(path)
    check_output_dir(path)
    fd, tmp_name = tempfile.mkstemp(
        prefix=f".{path.stem}.", suffix=path.suffix, dir=path.resolve().parent
    )
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        # mkstemp creates 0600; give the output the mode a plain open() would have.
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise



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
