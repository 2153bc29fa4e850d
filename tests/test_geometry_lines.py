"""graphtrack.geometry.lines: polar lines against hand-computed values."""
import numpy as np

from graphtrack.geometry.lines import line_in_image, narrowed


def test_line_in_image_clips_to_rectangle():
    ends = line_in_image(100.0, 0.0, 480, 270)  # x = 100
    np.testing.assert_allclose(sorted(ends[:, 1]), [0.0, 269.0])
    np.testing.assert_allclose(ends[:, 0], 100.0)
    assert line_in_image(-50.0, 0.0, 480, 270) is None


def test_narrowed_moves_each_line_towards_the_other():
    # x = 10 and x = 20 (theta 0); the second also written with the opposite normal (theta pi, rho -20)
    cos = np.array([[1.0, 1.0], [1.0, -1.0]])
    sin = np.zeros((2, 2))
    rho = np.array([[10.0, 20.0], [10.0, -20.0]])
    np.testing.assert_allclose(narrowed(rho, cos, sin, 1.5), [[11.5, 18.5], [11.5, -18.5]])
    np.testing.assert_allclose(narrowed(rho, cos, sin, np.array([-1.0, 2.0])), [[9.0, 21.0], [12.0, -18.0]])
    # a tilted pair: y = x and y = x + 10 * sqrt(2) (normal (-1, 1) / sqrt(2)), 0.5 px narrower
    c, s = np.cos(3 * np.pi / 4), np.sin(3 * np.pi / 4)
    out = narrowed(np.array([[0.0, 10.0]]), np.array([[c, c]]), np.array([[s, s]]), 0.5)
    np.testing.assert_allclose(out, [[0.5, 9.5]])
    # a line at infinity (an invalid hypothesis) stays there, and no NaN comes of it
    out = narrowed(np.array([[np.inf, 20.0]]), np.array([[1.0, 1.0]]), np.zeros((1, 2)), 1.0)
    assert out[0, 0] == np.inf and not np.isnan(out).any()
