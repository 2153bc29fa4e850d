"""graphtrack.detect.base.detector_image: what the detectors read, and the clear error a
caller's 16-bit, float, odd-shaped or empty array gets instead of an empty detection."""
import numpy as np
import pytest

from graphtrack.detect import make_detector
from graphtrack.detect.base import detector_image


def _frame():
    img = np.full((120, 160, 3), 40, np.uint8)
    img[:, 60:100] = 200                                  # a bright band: two vertical edges
    return img


def test_channels_are_read_as_grey_or_bgr():
    img = _frame()
    assert detector_image(img) is not None and detector_image(img).shape == (120, 160, 3)
    assert detector_image(img[:, :, :1]).shape == (120, 160)
    bgra = np.dstack([img, np.full(img.shape[:2], 255, np.uint8)])
    np.testing.assert_array_equal(detector_image(bgra), img)


@pytest.mark.parametrize("image, match", [
    (_frame().astype(np.uint16) * 257, "8-bit image .* got uint16"),
    (_frame() / 255.0, "got float64"),
    (np.zeros((120, 160, 2), np.uint8), r"got shape \(120, 160, 2\)"),
    (np.zeros(5, np.uint8), r"got shape \(5,\)"),
    (np.zeros((0, 160, 3), np.uint8), "empty image"),
])
@pytest.mark.parametrize("name", ["canny", "learned"])
def test_every_detector_refuses_what_it_cannot_read(name, image, match):
    det = make_detector(name)
    with pytest.raises(ValueError, match=match):
        det.detect(image)


@pytest.mark.parametrize("name", ["canny", "learned"])
def test_one_and_four_channels_detect_as_grey_and_bgr(name):
    det = make_detector(name)
    img = _frame()
    bgra = np.dstack([img, np.zeros(img.shape[:2], np.uint8)])
    np.testing.assert_array_equal(det.detect(bgra).segments, det.detect(img).segments)
    grey = img[:, :, 0]
    np.testing.assert_array_equal(det.detect(grey[:, :, None]).segments, det.detect(grey).segments)
