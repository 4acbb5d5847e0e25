"""Array aliases used in signatures and docstrings (numpy only)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IndexArray = npt.NDArray[np.int64]
AOArray = npt.NDArray[np.float64]
