"""Refactoring pin: the tracking pipeline replays a stored recording to the same trajectories.

``tests/data/replay/recording`` is a 40-frame 270x480 simulated tissue recording
stored as JPEG frames (so the simulator may change without moving the pin), and
``tests/data/replay/<case>.csv`` are the trajectories that graphtrack wrote for it
before a behaviour-preserving change (restructuring, moving code). A
restructuring must reproduce them; an intended change of an estimator's or
detector's behaviour regenerates them, saying why in the commit:

    python3 tests/test_replay_pin.py --write

This is not an accuracy test (the accuracy tests use independent truth); it
checks that code that was only moved still computes the same thing.
"""
from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).parent / "data" / "replay"
RECORDING = DATA / "recording"

#: case name -> (estimator, detector, observation model)
CASES = {
    "kinematics": ("kinematics", "learned", "line-intensities"),
    "pf-learned-line-intensities": ("pf", "learned", "line-intensities"),
    "pf-canny-canny": ("pf", "canny", "canny"),
    "smoother-learned-line-intensities": ("smoother", "learned", "line-intensities"),
    "smoother-canny-canny": ("smoother", "canny", "canny"),
    "smoother-learned-endpoints-polar": ("smoother", "learned", "endpoints-polar"),
    "batch-learned-endpoint-intensities": ("batch", "learned", "endpoint-intensities"),
}

#: columns compared (ms and smoother_ms are wall-clock and never compared)
POSE = ("tx", "ty", "tz", "qx", "qy", "qz", "qw")
TIP = ("tip_u", "tip_v")
STD = ("std_bx", "std_by", "std_bz", "std_wx", "std_wy", "std_wz")


def _run(case: str, out: Path) -> Path:
    import torch

    from graphtrack.detect.options import DetectionOptions
    from graphtrack.track import TrackOptions, track

    torch.set_num_threads(1)
    estimator, detector, observation = CASES[case]
    opts = TrackOptions(estimator=estimator, detection=DetectionOptions(detector=detector), observation=observation,
                        seed=3)
    track(RECORDING, out, opts, progress=False, quiet=True)
    return out / "trajectory.csv"


def _read(path: Path) -> dict[str, np.ndarray]:
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    cols = rows[0].keys() if rows else []
    return {c: np.array([float(r[c]) for r in rows]) for c in cols}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CASES))
def test_replay_reproduces_pinned_trajectory(case, tmp_path):
    pinned = _read(DATA / f"{case}.csv")
    got = _read(_run(case, tmp_path))
    np.testing.assert_array_equal(got["frame"], pinned["frame"])
    for cols, atol in ((POSE, 1e-6), (TIP, 1e-3), (STD, 1e-6)):
        for c in cols:
            if c in pinned:
                assert c in got, f"{case}: column {c} missing"
                np.testing.assert_allclose(got[c], pinned[c], rtol=0, atol=atol, equal_nan=True,
                                           err_msg=f"{case}: column {c}")


def write_pins() -> None:
    import shutil
    import tempfile

    for case in CASES:
        with tempfile.TemporaryDirectory() as d:
            shutil.copy(_run(case, Path(d)), DATA / f"{case}.csv")
        print(f"wrote {DATA / f'{case}.csv'}")


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        sys.exit("usage: python3 tests/test_replay_pin.py --write")
    write_pins()
