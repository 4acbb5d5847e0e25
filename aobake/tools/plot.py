"""matplotlib, loaded on demand for the tools' plots (an optional extra).

The only module that imports matplotlib; importing it loads nothing heavy.
"""

from __future__ import annotations

from ..errors import AobakeError


def pyplot(*, required: bool = True):
    """matplotlib.pyplot on the non-interactive Agg backend; without matplotlib (an
    optional dependency), :class:`AobakeError` saying so, or None if not ``required``."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        import matplotlib.ticker  # noqa: F401  (plots set tick formatters)
    except ImportError as exc:
        if not required:
            return None
        raise AobakeError(
            "plotting needs matplotlib, which is not installed (pip install matplotlib)"
        ) from exc
    return plt
