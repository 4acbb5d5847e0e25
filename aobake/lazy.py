"""Lazy exports: a package names what it offers, and the defining module is imported on
first use, so that ``import aobake`` and ``aobake --help`` load no numpy. Standard
library only."""

from __future__ import annotations

import importlib


def exports(package: str, table: dict[str, str]):
    """A module-level ``__getattr__`` for ``package``: ``name`` is looked up in
    ``package.<table[name]>`` when first asked for; other names raise AttributeError."""

    def __getattr__(name: str):
        module = table.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{module}"), name)

    return __getattr__
