"""The detection benchmark's contrast sweep (benchmarks/contrast_sweep.py): a frame scaled about
its mean keeps the mean, a dimmed one scales it, both scale the spread by c; the edge contrast
it reports scales with c."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from contrast_sweep import SWEEP_NOISE, edge_contrast, scale_contrast  # noqa: E402


def test_scale_contrast_keeps_the_mean_and_scales_the_spread():
    rng = np.random.default_rng(0)
    raw = rng.integers(40, 216, (120, 160, 3)).astype(np.uint8)
    out = scale_contrast(raw, 0.25, np.random.default_rng(1))
    f = raw.astype(float)
    assert out.dtype == np.uint8 and out.shape == raw.shape
    assert abs(out.mean() - f.mean()) < 0.1
    # var(c (I - m) + n) = c^2 var(I) + SWEEP_NOISE^2 (+ the rounding's 1/12)
    expected = np.sqrt(0.25 ** 2 * f.var() + SWEEP_NOISE ** 2 + 1 / 12)
    assert abs(out.std() - expected) < 0.02 * expected


def test_dimming_scales_the_mean_and_the_spread():
    rng = np.random.default_rng(3)
    raw = rng.integers(40, 216, (120, 160, 3)).astype(np.uint8)
    out = scale_contrast(raw, 0.25, np.random.default_rng(4), about_mean=False)
    f = raw.astype(float)
    assert abs(out.mean() - 0.25 * f.mean()) < 0.1
    expected = np.sqrt(0.25 ** 2 * f.var() + SWEEP_NOISE ** 2 + 1 / 12)
    assert abs(out.std() - expected) < 0.02 * expected


def test_edge_contrast_of_a_rendered_frame_scales_with_c():
    from graphtrack.sim.simulate import Simulation

    sim = Simulation("structured", 2, seed=3, size=(270, 480), noise_free=True)
    raw = sim.render(0)[0]
    full = edge_contrast(sim, 0, raw)
    assert full > 20.0    # a dark shaft on the white bench
    half = edge_contrast(sim, 0, scale_contrast(raw, 0.5, np.random.default_rng(2)))
    assert abs(half / full - 0.5) < 0.05
