"""Canny + Hough baseline on synthetic undistorted frames with known shaft edges.

``shaft_scene`` (imported by the other test_detect_* files) renders a grey
shaft band between two known lines with exact area coverage (4x supersampling
then INTER_AREA), clutter lines, an optional texture, noise and a blue marker.
"""
from __future__ import annotations


import cv2
import numpy as np
import pytest

from graphtrack.detect import make_detector
from graphtrack.detect.canny import CannyConfig, CannyDetector
from graphtrack.errors import InputError
from graphtrack.geometry.lines import line_difference, line_through

H, W = 540, 960
# shaft edges: (start, end) points in undistorted pixels
EDGE_A = (np.array([-20.0, 420.0]), np.array([620.0, 170.0]))
EDGE_B = (np.array([-20.0, 500.0]), np.array([640.0, 230.0]))
MARKER = (300.3, 262.6)


def _coverage(poly: np.ndarray, h: int, w: int, f: int = 4) -> np.ndarray:
    """Exact-ish area coverage (h, w) float in [0, 1] of a polygon in pixel coords."""
    hi = np.zeros((h * f, w * f), np.uint8)
    P = ((np.asarray(poly, float) + 0.5) * f - 0.5) * 16
    cv2.fillPoly(hi, [np.round(P).astype(np.int32)], 255, cv2.LINE_8, shift=4)
    return cv2.resize(hi, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0


def _disc_coverage(c, r: float, h: int, w: int, f: int = 8) -> np.ndarray:
    x0, y0 = int(c[0] - r - 2), int(c[1] - r - 2)
    n = int(2 * r + 5)
    hi = np.zeros((n * f, n * f), np.uint8)
    C = ((np.asarray(c, float) - [x0, y0] + 0.5) * f - 0.5) * 16
    cv2.circle(hi, (int(round(C[0])), int(round(C[1]))), int(round(r * f * 16)), 255, -1, cv2.LINE_8, 4)
    out = np.zeros((h, w), np.float32)
    out[y0:y0 + n, x0:x0 + n] = cv2.resize(hi, (n, n), interpolation=cv2.INTER_AREA) / 255.0
    return out


def truth_lines() -> np.ndarray:
    return np.array([line_through(*EDGE_A), line_through(*EDGE_B)], float).reshape(2, 2)


def shaft_scene(seed: int = 0, texture: float = 0.0, clutter: bool = True, noise: float = 3.0,
                marker=MARKER, tool: bool = True, h: int = H, w: int = W) -> np.ndarray:
    """BGR uint8 frame: background (white, or pinkish texture of amplitude ``texture``),
    a grey shaft band between EDGE_A and EDGE_B, clutter lines, a blue marker disc."""
    rng = np.random.default_rng(seed)
    if texture > 0:
        t = cv2.resize(rng.normal(0, 1, (h // 12 + 1, w // 12 + 1)).astype(np.float32), (w, h),
                       interpolation=cv2.INTER_CUBIC)
        img = np.stack([150 + texture * t, 125 + texture * t, 205 + texture * t], -1)
    else:
        img = np.full((h, w, 3), 230.0, np.float32)
    if clutter:
        for (p, q, col, th) in (((100, 40), (820, 110), 170, 3), ((700, 520), (900, 110), 60, 2),
                                ((420, 520), (520, 380), 120, 2)):
            layer = np.zeros((h, w), np.uint8)
            cv2.line(layer, p, q, 255, th, cv2.LINE_AA)
            a = layer.astype(np.float32)[..., None] / 255.0
            img = img * (1 - a) + col * a
    if tool:
        a = _coverage(np.array([EDGE_A[0], EDGE_A[1], EDGE_B[1], EDGE_B[0]]), h, w)[..., None]
        img = img * (1 - a) + np.array([95.0, 92.0, 90.0]) * a
    if marker is not None:
        a = _disc_coverage(marker, 8.0, h, w)[..., None]
        img = img * (1 - a) + np.array([255.0, 0.0, 0.0]) * a
    img = img + rng.normal(0, noise, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def assert_lines_close(found: np.ndarray, truth: np.ndarray, px: float = 2.0, rad: float = 0.02):
    """Offset at the image centre (px) and angle (rad) of each found line vs truth."""
    for f, t in zip(found, truth):
        _, dth = line_difference(f[0], f[1], t[0], t[1])
        # distance between the lines at the image centre's foot point on the truth line
        c = np.array([(W - 1) / 2, (H - 1) / 2])
        foot = c - (np.cos(t[1]) * c[0] + np.sin(t[1]) * c[1] - t[0]) * np.array([np.cos(t[1]), np.sin(t[1])])
        off = abs(np.cos(f[1]) * foot[0] + np.sin(f[1]) * foot[1] - f[0])
        assert abs(dth) < rad, (f, t)
        assert off < px, (f, t)


@pytest.mark.parametrize("texture", [0.0, 15.0])
def test_finds_both_edges_without_prediction(texture):
    img = shaft_scene(texture=texture)
    det = CannyDetector().detect(img)
    assert len(det.shaft_lines) == 2
    assert sorted(det.edge_ids.tolist()) == [0, 1]
    truth = truth_lines()
    # without a prediction the labelling is by offset along the normal: match by rho
    order = np.argsort(det.shaft_lines[:, 0])
    assert_lines_close(det.shaft_lines[order], truth[np.argsort(truth[:, 0])])
    assert det.heatmap.shape == (H, W) and det.heatmap.dtype == np.float32
    assert set(np.unique(det.heatmap)) <= {0.0, 1.0}
    assert len(det.segments) >= 3            # clutter lines are candidates too
    assert det.shaft_segments.shape == (2, 4)
    assert det.ms > 0


@pytest.mark.parametrize("swap", [False, True])
def test_prediction_gates_and_orders_edges(swap):
    img = shaft_scene(texture=10.0, seed=3)
    truth = truth_lines()
    pred = truth + np.array([[4.0, 0.03], [-5.0, -0.02]])
    if swap:
        pred = pred[::-1]
    det = CannyDetector().detect(img, pred)
    assert det.edge_ids.tolist() == [0, 1]
    expect = truth[::-1] if swap else truth
    assert_lines_close(det.shaft_lines, expect)
    # segments lie on their lines and span most of the visible shaft
    for (x1, y1, x2, y2), (rho, th) in zip(det.shaft_segments, det.shaft_lines):
        assert abs(np.cos(th) * x1 + np.sin(th) * y1 - rho) < 1e-6
        assert np.hypot(x2 - x1, y2 - y1) > 500


def test_hidden_edge_gives_one():
    img = shaft_scene()
    # cover edge B's neighbourhood with the shaft colour: only edge A remains
    big = np.array([EDGE_A[0], EDGE_A[1], [700.0, 400.0], [-20.0, 540.0]])
    cv2.fillPoly(img, [np.round(big).astype(np.int32)], (95, 92, 90))
    truth = truth_lines()
    det = CannyDetector().detect(img, truth)
    assert det.edge_ids.tolist() == [0]
    assert_lines_close(det.shaft_lines, truth[:1])


@pytest.mark.parametrize("frame", ["black", "white", "red", "blue", "tiny", "tiny_noise", "one_px",
                                   "no_tool", "no_tool_texture", "gray"])
def test_degenerate_frames(frame):
    rng = np.random.default_rng(1)
    img = {
        "black": np.zeros((H, W, 3), np.uint8),
        "white": np.full((H, W, 3), 255, np.uint8),
        "red": np.tile(np.array([0, 0, 255], np.uint8), (H, W, 1)),
        "blue": np.tile(np.array([255, 0, 0], np.uint8), (H, W, 1)),
        "tiny": np.zeros((8, 8, 3), np.uint8),
        "tiny_noise": rng.integers(0, 256, (8, 8, 3)).astype(np.uint8),
        "one_px": np.zeros((1, 1, 3), np.uint8),
        "no_tool": shaft_scene(tool=False, marker=None, clutter=False),
        "no_tool_texture": shaft_scene(tool=False, marker=None, clutter=False, texture=20.0),
        "gray": np.full((H, W), 128, np.uint8),
    }[frame]
    for pred in (None, truth_lines()):
        det = CannyDetector().detect(img, pred)
        assert len(det.shaft_lines) == 0 and len(det.shaft_segments) == 0
        assert len(det.edge_ids) == 0
        assert len(det.markers) == 0
        assert det.heatmap is not None and det.heatmap.shape == img.shape[:2]


def test_black_undistortion_border_is_ignored():
    """Black bands left and right (an undistortion's empty border): the shaft's two
    edges are still found at the truth, and no segment is the border's vertical
    step (every segment inside the bands, or far from vertical)."""
    img = shaft_scene(clutter=False)
    img[:, :80] = 0        # empty border left by an undistortion
    img[:, -80:] = 0
    for pred in (None, truth_lines()):
        det = CannyDetector().detect(img, pred)
        assert len(det.shaft_lines) == 2 and len(det.segments) >= 2
        assert_lines_close(det.shaft_lines, truth_lines())
        for x1, y1, x2, y2 in det.segments:
            assert min(x1, x2) > 60 and max(x1, x2) < W - 60 or abs(x1 - x2) > 20


def test_plain_hough_and_no_refine_options():
    img = shaft_scene()
    truth = truth_lines()
    det = CannyDetector(hough_orientation_tol=None).detect(img, truth)
    assert_lines_close(det.shaft_lines, truth)
    det = CannyDetector(refine=False).detect(img, truth)
    assert len(det.shaft_lines) == 2
    assert_lines_close(det.shaft_lines, truth, px=15.0, rad=0.05)  # Hough bins only
    det = CannyDetector(scale=1.0).detect(img, truth)
    assert_lines_close(det.shaft_lines, truth)


def test_factory_and_options():
    d = make_detector("canny", votes=80, low_threshold=30)
    assert isinstance(d, CannyDetector) and d.name == "canny"
    assert d.config.votes == 80 and d.config.low_threshold == 30
    cfg = CannyConfig()
    CannyDetector(cfg, votes=10)
    assert cfg.votes == 100  # the caller's config is not modified
    with pytest.raises(TypeError):
        CannyDetector(no_such_option=1)
    with pytest.raises(InputError):
        make_detector("no-such-detector")
    with pytest.raises(ValueError):
        CannyDetector().detect(np.zeros((10, 10, 3), np.float32))


def test_widened_gates_per_call():
    from graphtrack.detect.association import AssociationConfig

    img = shaft_scene()
    # predictions turned by 0.2 rad about each edge's midpoint: outside the default 0.15 rad gate
    far = []
    for a, b in (EDGE_A, EDGE_B):
        m, d = (a + b) / 2, (b - a) / 2
        c, s = np.cos(0.2), np.sin(0.2)
        d = np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]])
        far.append(line_through(m - d, m + d))
    far = np.array(far, float).reshape(2, 2)
    d = CannyDetector()
    assert len(d.detect(img, far).shaft_lines) == 0
    wide = d.detect(img, far, association=AssociationConfig(max_angle=0.3))
    assert wide.edge_ids.tolist() == [0, 1]
    assert_lines_close(wide.shaft_lines, truth_lines())
