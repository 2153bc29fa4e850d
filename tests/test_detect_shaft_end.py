"""The shaft-end detector on a drawn band (the step's position by construction) and on the
simulator's ray-cast frames (the end rim's front point, projected through the true pose)."""
import numpy as np
import pytest

from graphtrack.detect.shaft_end import locate, raw_sampler
from graphtrack.geometry.cylinder import project_cylinder
from graphtrack.geometry.shaft_end import front_point
from graphtrack.robot.psm import SHAFT_END, SHAFT_RADIUS
from graphtrack.sim.simulate import Simulation

H, W = 240, 320
ANGLE = 0.3                      # rad, the band's direction (distal: +d)
D = np.array([np.cos(ANGLE), np.sin(ANGLE)])
N = np.array([-D[1], D[0]])
O = np.array([150.3, 110.7])     # the band's end, on its axis
HALF = 14.0                      # px, half-width


def _band(end_grey=200.0, shaft=40.0, background=120.0, blob=None, supersample=4, wrist=30.0):
    """A dark band along D ending at O, a brighter 'wrist' band after it, antialiased by
    supersampling; ``blob``: (s, radius, grey) a disc on the band's axis at O + s D."""
    k = supersample
    y, x = np.mgrid[0:H * k, 0:W * k]
    p = np.stack([(x + 0.5) / k - 0.5, (y + 0.5) / k - 0.5], -1) - O
    s, t = p @ D, p @ N
    img = np.full(s.shape, background)
    img[(np.abs(t) < HALF) & (s < 0)] = shaft
    img[(np.abs(t) < 0.9 * HALF) & (s >= 0) & (s < wrist)] = end_grey
    if blob is not None:
        img[np.hypot(s - blob[0], t) < blob[1]] = blob[2]
    return img.reshape(H, k, W, k).mean((1, 3)).astype(np.uint8)


def _lines_and_segments():
    lines, segs = [], []
    for side in (-1, 1):
        n = side * N
        a, b = O + side * HALF * N - 150 * D, O + side * HALF * N
        lines.append([n @ a, np.arctan2(n[1], n[0])])
        segs.append(np.concatenate([a, b]))
    return np.array(lines), np.array(segs)


def _offset(end):
    return float(end.direction @ (end.point - O))


def test_finds_the_drawn_step_to_a_fraction_of_a_pixel():
    lines, segs = _lines_and_segments()
    end = locate(raw_sampler(_band()), lines, segs, D)
    assert end is not None and abs(_offset(end)) < 0.3
    assert np.allclose(end.direction, D, atol=1e-6)
    # the segments ending 10 px short of the step (a detector's coarse end) do not move it
    short = segs.copy()
    short[:, 2:] -= 10 * D
    assert abs(_offset(locate(raw_sampler(_band()), lines, short, D))) < 0.3


def test_segments_running_past_the_end_are_covered_by_the_prediction():
    """A detector's segments may run on past the shaft's end (along the narrower wrist's
    edges): 70 px past it, the profile around their end sees only the background, and
    the end is found only when the predicted end (3 px off) widens the profile."""
    lines, segs = _lines_and_segments()
    long = segs.copy()
    long[:, 2:] += 70 * D
    img = raw_sampler(_band())
    assert locate(img, lines, long, D) is None
    end = locate(img, lines, long, D, predicted=O + 3.0 * D)
    assert end is not None and abs(_offset(end)) < 0.3


def test_a_marker_on_the_shaft_does_not_move_it():
    lines, segs = _lines_and_segments()
    end = locate(raw_sampler(_band(blob=(-12.0, 3.5, 230.0))), lines, segs, D)
    assert end is not None and abs(_offset(end)) < 0.3


def test_no_step_or_the_wrong_polarity_is_no_end():
    lines, segs = _lines_and_segments()
    assert locate(raw_sampler(_band(end_grey=40.0, wrist=80.0)), lines, segs, D) is None  # band goes on
    assert locate(raw_sampler(_band(end_grey=30.0, shaft=200.0, wrist=80.0)), lines, segs, D) is None  # bright to dark
    assert locate(raw_sampler(_band()), lines[:1], segs[:1], D) is None            # one edge only


@pytest.fixture(scope="module")
def clean():
    return Simulation("structured", 4, seed=5, size=(360, 640), noise_free=True)


def test_simulated_frames_end_at_the_rim_front_point(clean):
    """Given the true silhouette lines, the detected end is the projection of the end rim's
    front point of the true pose (graphtrack.geometry.shaft_end), along the shaft's image."""
    cam = clean.camera
    for i in range(3):
        img, _ = clean.render(i)
        L4 = clean.L_true[i, 4]
        p0, d = L4[:3, 3], L4[:3, 2]
        rho, theta, valid = project_cylinder(p0, d, SHAFT_RADIUS, cam.K)
        assert valid
        c = p0 + SHAFT_END * d
        uv = np.stack([c - 0.05 * d, c]) @ cam.K.T
        uv = uv[:, :2] / uv[:, 2:]
        lines = np.stack([rho, theta], -1)
        segs = []
        for r, th in lines:     # each limb between the feet of the two axis points
            n = np.array([np.cos(th), np.sin(th)])
            segs.append(np.concatenate([q - (n @ q - r) * n for q in uv]))
        end = locate(raw_sampler(img, cam), lines, np.array(segs), uv[1] - uv[0])
        P = front_point(c, d, SHAFT_RADIUS) @ cam.K.T
        assert end is not None
        assert abs(end.direction @ (end.point - P[:2] / P[2])) < 0.5
