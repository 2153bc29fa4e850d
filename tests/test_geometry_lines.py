"""graphtrack.geometry.lines: polar lines against hand-computed values."""
import numpy as np

from graphtrack.geometry.lines import line_in_image


def test_line_in_image_clips_to_rectangle():
    ends = line_in_image(100.0, 0.0, 480, 270)  # x = 100
    np.testing.assert_allclose(sorted(ends[:, 1]), [0.0, 269.0])
    np.testing.assert_allclose(ends[:, 0], 100.0)
    assert line_in_image(-50.0, 0.0, 480, 270) is None
