"""What a randomized recording draws over time, and scenario.json (its record).

:func:`draw_events` schedules, on the frame axis of an n-frame recording,
an out-of-view excursion (probability 0.5; held 0.5-3 s, ramps 0.4-1 s) and
0-2 occlusions (P = 0.15 / 0.55 / 0.30; each 0.5-3 s, target coverage
U(0.3, 1.0)) in random order, separated by 0.7-1.5 s of clear view so that
re-acquisition can be measured after each; an event that no longer fits is
shortened (down to 0.5 s) or dropped.

scenario.json (written beside truth.csv, for evaluation only; the estimator
never reads it) holds: ``handeye_error`` (translation mm, rotation deg and
the 4x4 Delta), ``occlusions`` (kind, frames [start, end), target and
measured per-frame coverage), ``out_of_view`` (the planned excursion and the
measured intervals where the tip, resp. the whole shaft, is outside the
image), ``effects`` (on/off and parameters) and ``look`` (scene draws).
Intervals are half-open [start, end) frame indices.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

FPS = 30.0
MIN_EVENT = int(0.5 * FPS)


def draw_events(rng, n: int) -> list[tuple]:
    """[(kind 'excursion' | 'occlusion', start, length, extra)] in frame order (module doc)."""
    wanted = ["excursion"] if rng.uniform() < 0.5 else []
    wanted += ["occlusion"] * int(rng.choice([0, 1, 2], p=[0.15, 0.55, 0.30]))
    rng.shuffle(wanted)
    t = int(rng.integers(int(0.3 * FPS), int(1.0 * FPS)))
    out = []
    for kind in wanted:
        hold = int(rng.integers(MIN_EVENT, int(3.0 * FPS) + 1))
        if kind == "excursion":
            ramp = int(rng.integers(int(0.4 * FPS), int(1.0 * FPS) + 1))
            hold = min(hold, n - t - 2 * ramp - 5)
            if hold < MIN_EVENT:
                continue
            out.append((kind, t, 2 * ramp + hold, {"ramp": ramp, "hold": hold}))
            t += 2 * ramp + hold
        else:
            hold = min(hold, n - t - 5)
            if hold < MIN_EVENT:
                continue
            out.append((kind, t, hold, {"target": float(rng.uniform(0.3, 1.0))}))
            t += hold
        t += int(rng.integers(int(0.7 * FPS), int(1.5 * FPS) + 1))
    return out


def intervals(flags: np.ndarray) -> list[list[int]]:
    """Runs of True in a boolean per-frame array -> [[start, end), ...]."""
    f = np.concatenate([[False], np.asarray(flags, bool), [False]])
    d = np.flatnonzero(np.diff(f.astype(int)))
    return [[int(a), int(b)] for a, b in zip(d[::2], d[1::2])]


def _clean(v):
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    if isinstance(v, np.ndarray):
        return _clean(v.tolist())
    if isinstance(v, (np.floating, float)):
        return None if not np.isfinite(v) else float(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    return v


def write_scenario(path: str | Path, doc: dict) -> None:
    """scenario.json (NaN written as null)."""
    Path(path).write_text(json.dumps(_clean(doc), indent=1) + "\n")
