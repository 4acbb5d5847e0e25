"""Options as data: one dataclass field per user choice, carrying its default, help text,
command-line flag and valid range, so each is spelled once.

A method's options class is a frozen dataclass made of :func:`option` fields; its
``__post_init__`` calls :func:`validate`, and the CLI builds its click options from the
same fields (:func:`specs`). Imports only the standard library (``aobake --help`` stays
instant).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Spec:
    """What one option field accepts and how the CLI shows it.

    Attributes
    ----------
    help : str
        One line for ``--help`` (the CLI appends the default).
    kind : {int, float, bool, str}
    flag : str
        Command-line flag without the dashes (default: the field name, ``_`` -> ``-``).
    low, high : float or None
        Bounds of numbers; ``low_open`` / ``high_open`` exclude them.
    choices : tuple of str or None
        The values a ``str`` option takes.
    none : str or None
        When None is allowed, what it means (shown as the default: "unbounded").
    finite : bool
        Numbers must be finite (every option so far).
    """

    help: str
    kind: type
    flag: str = ""
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] | None = None
    none: str | None = None
    finite: bool = True

    def describe(self) -> str:
        """The accepted values in words: "an integer >= 1", "a number > 0", "one of a, b"."""
        if self.kind is bool:
            return "True or False"
        if self.choices is not None:
            return "one of " + ", ".join(self.choices)
        noun = "an integer" if self.kind is int else "a finite number" if self.finite else "a number"
        parts = []
        if self.low is not None:
            parts.append(f"{'>' if self.low_open else '>='} {_number(self.low)}")
        if self.high is not None:
            parts.append(f"{'<' if self.high_open else '<='} {_number(self.high)}")
        text = noun + (" " + " and ".join(parts) if parts else "")
        return text + (f" or None ({self.none})" if self.none else "")


def option(default: Any, help: str, *, kind: type, **spec: Any) -> Any:
    """A dataclass field for an option: ``theta: float = option(2.0, "...", kind=float, low=0,
    low_open=True)``. Keywords are :class:`Spec`'s."""
    return dataclasses.field(default=default, metadata={"spec": Spec(help=help, kind=kind, **spec)})


def specs(options_class) -> dict[str, tuple[Spec, Any]]:
    """``{name: (Spec, default)}`` of an options class, in field order."""
    return {
        f.name: (f.metadata["spec"], f.default)
        for f in dataclasses.fields(options_class)
        if "spec" in f.metadata
    }


def flag(name: str, spec: Spec) -> str:
    """The command-line flag of field ``name``: ``--max-distance``."""
    return "--" + (spec.flag or name.replace("_", "-"))


def validate(options) -> None:
    """Check every option field of a (frozen) dataclass instance and store it coerced
    (``int`` or ``float``); raise ``ValueError("theta must be a finite number > 0, got -1")``
    otherwise."""
    for name, (spec, _) in specs(type(options)).items():
        value = getattr(options, name)
        checked = _check(spec, value)
        if checked is _BAD:
            raise ValueError(f"{name} must be {spec.describe()}, got {value!r}")
        object.__setattr__(options, name, checked)


def replace(options, **changes):
    """A copy of ``options`` with ``changes``; unknown names raise ``TypeError`` naming the
    class's options."""
    known = specs(type(options))
    unknown = sorted(set(changes) - set(known))
    if unknown:
        raise TypeError(
            f"{type(options).__name__} has no option {unknown[0]!r}; options: {', '.join(known)}"
        )
    return dataclasses.replace(options, **changes)


def build(options_class, options=None, **changes):
    """``options_class(**changes)``, or ``options`` (an instance) with ``changes``, or an
    instance from a dict; unknown names raise ``TypeError``."""
    if options is None:
        options = options_class()
    elif isinstance(options, dict):
        changes = {**options, **changes}
        options = options_class()
    elif not isinstance(options, options_class):
        raise TypeError(f"expected {options_class.__name__}, got {type(options).__name__}")
    return replace(options, **changes) if changes else options


_BAD = object()


def _check(spec: Spec, value):
    """``value`` coerced to the option's kind, or ``_BAD``."""
    if value is None:
        return None if spec.none else _BAD
    if spec.kind is bool:
        return value if isinstance(value, bool) else _BAD
    if spec.kind is str:
        return value if isinstance(value, str) and value in (spec.choices or (value,)) else _BAD
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return _BAD
    if spec.kind is int:
        if not isinstance(value, numbers.Integral):
            return _BAD
        value = int(value)
    else:
        value = float(value)
        if math.isnan(value) or (spec.finite and math.isinf(value)):
            return _BAD
    if spec.low is not None and (value < spec.low or (spec.low_open and value == spec.low)):
        return _BAD
    if spec.high is not None and (value > spec.high or (spec.high_open and value == spec.high)):
        return _BAD
    return value


def _number(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


# -- fields several commands share (each default spelled here once) -------------------

MEASURES = ("cosine", "uniform")


def measure_option():
    return option(
        "cosine",
        "cosine: A = 1/pi int V cos; uniform: the solid-angle fraction 1/(2 pi) int V.",
        kind=str,
        choices=MEASURES,
    )


def max_distance_option():
    return option(
        None,
        "Ignore geometry farther than this from the vertex (mesh units).",
        kind=float,
        low=0,
        low_open=True,
        none="unbounded",
    )


def bounces_option():
    """``--bounces``: the same field, default and help for every method that computes light."""
    return option(1, "Indirect bounces of light (lit scenes; 0 = direct light only).", kind=int, low=0, high=64)


def seed_option():
    return option(0, "Random seed.", kind=int, low=0, high=2**63 - 1)


def threads_option():
    return option(None, "Worker threads; the result does not depend on it.", kind=int, low=1, none="all cores")
