"""Time stamps of a recorded stream: the one estimate of its period that the readers share."""
from __future__ import annotations

import numpy as np


def median_interval(stamps) -> float:
    """The median of the positive, finite intervals between consecutive ``stamps`` (their
    unit: s or ns), 0.0 when there are none (fewer than two stamps, or all equal). Repeated
    stamps (a message recorded twice) do not shorten the period."""
    dt = np.diff(np.asarray(stamps)).astype(float)   # integer ns differenced exactly, then float
    dt = dt[np.isfinite(dt) & (dt > 0)]
    return float(np.median(dt)) if dt.size else 0.0
