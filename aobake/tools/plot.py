"""matplotlib, loaded on demand for the tools' plots (an optional extra).

The only module that imports matplotlib; importing it loads nothing heavy.
"""

from __future__ import annotations

from ..errors import AobakeError


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend, or :class:`AobakeError`
    naming the extra to install (matplotlib is optional)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        import matplotlib.ticker  # noqa: F401  (plots set tick formatters)
    except ImportError as exc:
        raise AobakeError("plotting needs matplotlib: pip install 'aobake[plot]'") from exc
    return plt
