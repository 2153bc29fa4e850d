"""Turning the learned net's input (graphtrack.detect.turn) and the detector that uses it."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from graphtrack.detect.turn import BLIND_DEG, edge_angle, turn_for, turned, turned_back


def _line(angle_deg: float, rho: float = 50.0) -> np.ndarray:
    """A polar line (rho, theta) whose image direction is angle_deg (y down)."""
    return np.array([rho, math.radians(angle_deg) + math.pi / 2])


def test_edge_angle_is_the_image_direction_averaged_as_axes():
    # hand-computed: theta 0 is the vertical line x = rho, theta pi/2 the horizontal y = rho
    assert edge_angle([[10.0, 0.0]]) == pytest.approx(90.0)
    assert edge_angle([[10.0, math.pi / 2]]) == pytest.approx(0.0, abs=1e-9)
    assert edge_angle([_line(30.0)]) == pytest.approx(30.0)
    # two edges either side of the vertical average to the vertical, not to the horizontal
    assert abs(edge_angle([_line(89.0), _line(-89.0)])) == pytest.approx(90.0)
    assert edge_angle(None) is None and edge_angle(np.full((2, 2), np.nan)) is None


@pytest.mark.parametrize("angle", np.arange(-89.5, 90.0, 2.0))
def test_a_turn_takes_every_blind_angle_out_of_the_blind_zone(angle):
    deg = turn_for([_line(angle)])
    blind = abs(angle) < BLIND_DEG[0] or abs(angle) > BLIND_DEG[1]
    assert (deg != 0.0) == blind
    if not blind:
        return
    # the turned direction, through the canvas's own affine map (OpenCV's rotation)
    _, A = turned(np.zeros((135, 240, 3), np.uint8), deg)
    d = A[:, :2] @ np.array([math.cos(math.radians(angle)), math.sin(math.radians(angle))])
    a = math.degrees(math.atan2(d[1], d[0]))
    a = (a + 90.0) % 180.0 - 90.0
    assert BLIND_DEG[0] + 4.0 <= abs(a) <= BLIND_DEG[1] - 4.0


def test_turned_holds_the_whole_image_and_turns_back():
    h, w = 135, 240
    img = np.zeros((h, w), np.uint8)
    cv2.line(img, (20, 100), (220, 30), 255, 1, cv2.LINE_AA)
    canvas, A = turned(img, 45.0)
    assert canvas.shape == (math.ceil((w + h) / math.sqrt(2)),) * 2
    # every corner of the image lands on the canvas
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], float)
    mapped = corners @ A[:, :2].T + A[:, 2]
    assert mapped.min() >= -1e-9 and mapped.max() <= canvas.shape[0] - 1 + 1e-9
    # the line's pixels sit where A puts them
    ys, xs = np.nonzero(canvas > 128)
    a, b = np.array([20, 100.0]) @ A[:, :2].T + A[:, 2], np.array([220, 30.0]) @ A[:, :2].T + A[:, 2]
    n = np.array([a[1] - b[1], b[0] - a[0]]) / np.hypot(*(b - a))
    assert np.abs((np.stack([xs, ys], 1) - a) @ n).max() < 1.0
    # a smooth map comes back onto the image's pixels
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    m = np.sin(xx / 17.0) + np.cos(yy / 11.0)
    c2, A2 = turned(m, -45.0)
    back = turned_back(c2, A2, (h, w))
    assert np.abs(back - m)[2:-2, 2:-2].max() < 0.02


@pytest.mark.parametrize("shaft_angle", [0.0, 90.0, 180.0])
def test_the_detector_finds_a_shaft_that_lies_along_an_image_axis(shaft_angle):
    # oracle: the simulator's true limb lines (Chaumette's projection at the true pose);
    # the shaft enters from the right (0), the top (90) or the left (180)
    import torch

    from graphtrack.detect.learned import LearnedDetector
    from graphtrack.geometry.lines import line_difference
    from graphtrack.robot.features import base_features, shaft_lines
    from graphtrack.sim.simulate import Simulation

    torch.set_num_threads(1)
    detector = LearnedDetector()
    sim = Simulation("tissue", 10, seed=4242, size=(540, 960), shaft_angle=shaft_angle)
    raw, _ = sim.render(5)
    rho, th, ok = shaft_lines(base_features(sim.robot, sim.q_read[5]).transformed(sim.E_t[5]), sim.camera.K)
    assert ok and turn_for(np.stack([rho, th], 1)) != 0.0
    det = detector.detect(raw, np.stack([rho, th], 1), camera=sim.camera)
    assert len(det.shaft_lines) == 2 and sorted(det.edge_ids.tolist()) == [0, 1]
    for (r, t), j in zip(det.shaft_lines, det.edge_ids):
        dr, dt = line_difference(r, t, rho[j], th[j])
        assert abs(dr) < 1.0 and abs(dt) < 3e-3
