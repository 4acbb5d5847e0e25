"""The one exception family of aobake; the CLI turns these into one-line errors.

Imports nothing from aobake.
"""

from __future__ import annotations

from pathlib import Path


class AobakeError(Exception):
    """Base class: an expected failure with a one-line, user-facing message."""


class InputError(AobakeError):
    """An input file (mesh or field) is unreadable or invalid.

    Raised by loaders and validators; the message starts with the file name so a batch
    run says which file failed: ``"scan.ply: 12 faces reference vertex 3402 but the mesh
    has 3400 vertices"``.
    """

    def __init__(self, path: str | Path | None, problem: str):
        self.path = None if path is None else Path(path)
        self.problem = problem
        name = "<input>" if path is None else Path(path).name
        super().__init__(f"{name}: {problem}")


class SettingError(InputError):
    """An option's value does not fit the input it is applied to (``--ground`` above the
    mesh): named after the input, a usage error (exit 2) on the command line."""

    exit_code = 2


class FormatError(AobakeError):
    """An output path has a suffix no writer supports (raised before any computation)."""


class OutputError(AobakeError):
    """An output cannot be written (missing or unwritable directory, disk full)."""


class NumericalError(AobakeError):
    """A method produced a non-finite or out-of-range result (a bug, reported plainly)."""
