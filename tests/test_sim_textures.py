"""Procedural backgrounds (graphtrack.sim.textures): shape, dtype, range, seeds."""
import numpy as np
import pytest

from graphtrack.sim import textures

H, W = 90, 160


def rng(seed=0):
    return np.random.default_rng(seed)


def test_fractal_noise_range_and_seed():
    """Each octave is a bicubic upsampling of U(-1, 1) (overshoot <= 1.25x), weights
    normalised: |n| <= 1.25; non-constant; the same seed, the same array."""
    n = textures.fractal_noise(rng(), H, W, base=32, octaves=4)
    assert n.shape == (H, W) and n.dtype == np.float32
    assert np.abs(n).max() <= 1.25 and n.std() > 0.05
    np.testing.assert_array_equal(n, textures.fractal_noise(rng(), H, W, base=32, octaves=4))
    assert not np.array_equal(n, textures.fractal_noise(rng(1), H, W, base=32, octaves=4))


def test_vignette_by_hand():
    """Gain 1 - s r^2: 1 at the centre, 1 - s at the corners, symmetric."""
    v = textures.vignette(5, 7, 0.4)
    assert v.shape == (5, 7) and v.dtype == np.float32
    assert v[2, 3] == pytest.approx(1.0)
    for corner in (v[0, 0], v[0, -1], v[-1, 0], v[-1, -1]):
        assert corner == pytest.approx(0.6)
    np.testing.assert_allclose(v, v[::-1, ::-1])
    # r^2 = ((u - 3)^2 + (v - 2)^2) / (3^2 + 2^2): at (row 2, col 0) 9 / 13
    assert v[2, 0] == pytest.approx(1 - 0.4 * 9 / 13)


def test_white_bench_is_bright_and_flat():
    img = textures.white_bench(rng(), H, W)
    assert img.shape == (H, W, 3) and img.dtype == np.uint8
    assert 225 <= img.min() and img.max() <= 245          # level 236 +- 3 + 2 (gradient, tint)
    np.testing.assert_array_equal(img, textures.white_bench(rng(5), H, W))   # no randomness


@pytest.mark.parametrize("make", ["tissue", "random_background"])
def test_backgrounds_shape_range_and_seed(make):
    fn = getattr(textures, make)
    vig = textures.vignette(H, W, 0.3)
    a = fn(rng(2), H, W, vig=vig)
    assert a.shape == (H, W, 3) and a.dtype == np.uint8
    assert a.std() > 1.0                                   # textured, not flat
    np.testing.assert_array_equal(a, fn(rng(2), H, W, vig=vig))
    assert not np.array_equal(a, fn(rng(3), H, W, vig=vig))


def test_tissue_is_reddish():
    """The default base colour (B, G, R) = (95, 92, 190): red dominates on average."""
    img = textures.tissue(rng(4), H, W).reshape(-1, 3).mean(0)
    assert img[2] > 1.5 * img[0] and img[2] > 1.5 * img[1]


def test_noise_bank_parts():
    """positive - negative = the rounded Gaussian draw clipped to +-255, std ~ sigma."""
    pos, neg = textures.noise_bank(rng(), H, W, 4.0, pad=8)
    assert pos.shape == neg.shape == (H + 8, W + 8, 3) and pos.dtype == neg.dtype == np.uint8
    assert not np.any((pos > 0) & (neg > 0))
    n = pos.astype(np.int16) - neg.astype(np.int16)
    assert n.std() == pytest.approx(4.0, rel=0.05) and abs(n.mean()) < 0.1
    want = np.round(rng().normal(0, 4.0, (H + 8, W + 8, 3)))
    np.testing.assert_array_equal(n, want)
