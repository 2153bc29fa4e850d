"""Robustness figures against hand-computed cases."""
import math

import numpy as np
import pytest

from graphtrack.eval.robustness import (frames_to_converge, reacquisition_frames, recording_figures, segments,
                                        startup_frames, worst_window_excess)


def test_segments():
    assert segments(100, []) == [(0, 100)]
    assert segments(100, [(20, 30), (25, 40), (90, 120)]) == [(0, 20), (40, 90)]
    assert segments(50, [(0, 10)]) == [(10, 50)]
    assert segments(10, [(3, 3)]) == [(0, 10)]


def test_frames_to_converge():
    e = np.array([30, 20, 9, 4, 6, 3, 2, 1, 1, 1.0])
    assert frames_to_converge(e) == 5          # frame 4 (6 px) is the last above 5 px
    assert frames_to_converge(e, threshold=10) == 2
    assert frames_to_converge(np.ones(4)) == 0
    assert frames_to_converge(np.array([1, 1, 9.0])) == math.inf  # above at the end: never
    assert frames_to_converge(np.array([1, np.nan, 1.0])) == 2     # NaN counts as not converged
    assert math.isnan(frames_to_converge(np.ones(3), 3, 3))


def test_reacquisition_and_startup():
    e = np.array([9, 9, 1, 1, 1, 1, 50, 50, 50, 30, 20, 4, 1, 1, 1.0])
    dist = [(6, 9)]                           # frames 6-8 occluded
    assert startup_frames(e, dist) == 2
    assert reacquisition_frames(e, dist) == [2]  # frames 9, 10 above: re-acquired 2 frames after the end
    assert math.isnan(startup_frames(e, [(0, 3)]))


def test_worst_window_excess():
    base = np.full(30, 10.0)
    est = np.full(30, 2.0)
    est[12:15] = 40.0                          # a 3-frame excursion: window mean 2 + 3*38/10 = 13.4
    assert worst_window_excess(est, base, 10) == pytest.approx(3.4)
    assert worst_window_excess(np.full(30, 2.0), base) == pytest.approx(-8.0)
    assert math.isnan(worst_window_excess(np.ones(5), np.ones(5), 10))
    est[28] = np.nan                           # left out of the mean, not a zero
    assert worst_window_excess(est, base, 10) == pytest.approx(3.4)


def test_recording_figures():
    e = np.r_[np.linspace(40, 1, 10), np.ones(20)]   # frame 8 is 5.33 px: converged from frame 9
    f = recording_figures(e, np.full(30, 20.0), [])
    assert f["startup_frames"] == 9 and f["reacquire_frames"] == []
    assert f["mean_px"] == pytest.approx(np.mean(e))


def test_nan_window_mean_uses_finite_frames_only():
    base = np.full(20, 10.0)
    est = np.full(20, 2.0)
    est[0] = np.nan
    # the first window holds 9 finite frames of -8 px: mean -8, not -7.2
    assert worst_window_excess(est, base, 10) == pytest.approx(-8.0)


def test_recording_figures_segments():
    e = np.ones(40)
    f = recording_figures(e, np.full(40, 5.0), [(10, 20), (30, 35)])
    assert f["startup_segment"] == 10 and f["reacquire_segments"] == [10, 5]
    assert f["reacquire_frames"] == [0, 0]
