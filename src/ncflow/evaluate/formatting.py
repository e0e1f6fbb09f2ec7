"""Number formatting shared by the evaluation summary and the benchmark report.

JSON values are read as floats (``null`` and non-numbers become NaN) and printed with a format
spec, NaN as ``n/a``.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def format_number(value: Any, spec: str = ".4f") -> str:
    """``value`` (see :func:`as_number`) formatted with ``spec``, or ``"n/a"`` when it is not finite."""
    v = as_number(value)
    return format(v, spec) if np.isfinite(v) else "n/a"


def as_number(value: Any) -> float:
    """A float from a JSON value (None and non-numbers become NaN)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")
