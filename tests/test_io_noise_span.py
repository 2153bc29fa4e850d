"""noise_span (damaged raw image data) against a direct reading of its definition."""
from __future__ import annotations

import numpy as np
import pytest

from graphtrack.io.image_msg import NOISE_LEVEL, NOISE_WINDOW_PX, noise_span


def _oracle(image: np.ndarray) -> str | None:
    """The docstring, literally: green values in row-major pixel order, per window of
    NOISE_WINDOW_PX pixels the mean |g[i+1] - g[i]| over every 4th i of the window."""
    g = [int(v) for v in (image[..., 1] if image.ndim == 3 else image).reshape(-1)]
    d = []
    for k in range(len(g) // NOISE_WINDOW_PX):
        w = g[k * NOISE_WINDOW_PX:(k + 1) * NOISE_WINDOW_PX]
        d.append(np.mean([abs(w[i + 1] - w[i]) for i in range(0, NOISE_WINDOW_PX, 4)]))
    bad = [k for k, v in enumerate(d) if v > NOISE_LEVEL]
    if not d or not bad or np.median(d) > NOISE_LEVEL / 2:
        return None
    cols = image.shape[1]
    r0, r1 = bad[0] * NOISE_WINDOW_PX // cols, ((bad[-1] + 1) * NOISE_WINDOW_PX - 1) // cols
    return f"image rows {r0}..{r1} hold random-looking bytes (damaged image data)"


SHAPES = [(60, 96, 3), (37, 51, 3), (40, 64), (30, 70, 4), (3, 3, 3)]


def _check(shape) -> list:
    """noise_span == the oracle on clean and randomly damaged images; the oracle's answers."""
    rng = np.random.default_rng(sum(shape))
    ramp = (np.arange(shape[1]) % 50).astype(np.uint8).reshape((1, -1) + (1,) * (len(shape) - 2))
    clean = (rng.random(shape) * 20).astype(np.uint8) + ramp
    found = []
    for trial in range(6):
        img = clean.copy()
        flat = img.reshape(-1)
        if trial and flat.size > 64:
            a = int(rng.integers(0, flat.size - 8))
            b = min(flat.size, a + int(rng.integers(8, 6000)))
            flat[a:b] = rng.integers(0, 256, b - a)
        for view in (img, img[:, ::-1], img[::2]):   # non-contiguous images too
            assert noise_span(view) == _oracle(view)
            found.append(_oracle(view))
    return found


@pytest.mark.parametrize("shape", SHAPES)
def test_noise_span_matches_its_definition(shape):
    _check(shape)


def test_the_cases_include_damage_found():
    found = [x for shape in SHAPES for x in _check(shape)]
    assert sum(x is not None for x in found) >= 3
