"""Turning the learned net's input towards the shaft orientations it detects.

The shipped learned detector was trained on the simulator's views, whose shaft enters
from an upper edge 20-65 deg from the horizontal, flipped both ways. It misses shaft
edges that lie near an image axis: swept on held-out frames turned about their centre,
the net's line heatmap on the true edges falls to ~0.1 or below within 10 deg of the
horizontal and beyond 75 deg (docs/decisions/net-orientation.md). A real view has the
tool at any angle, so when the predicted shaft lies in that blind zone the net's input
is turned by 45 deg, and its maps are turned back:

    edge angle  a = theta + 90 deg, wrapped into (-90, 90]   (image direction of a
                                                             polar line (rho, theta),
                                                             y down)
    blind:      |a| < BLIND_DEG[0]  or  |a| > BLIND_DEG[1]
    turn:       phi = +45 deg if a > 0 else -45 deg          (OpenCV's sign:
                                                             counter-clockwise on screen),
                which takes the edge to a - phi: (0, 15) -> (-45, -30), (70, 90] ->
                (25, 45], (-15, 0] -> (30, 45], [-90, -70) -> [-45, -25).

The zone's bounds are where the net's median heatmap on the true edges of the sweep's
frames falls below 0.95 (the 10-15 and 70-75 deg bins: 0.92, 0.70).

The turned image lies on a canvas that holds all of it, (w + h) / sqrt(2) square for
45 deg (a 135x240 input: 266x266, 2.2 times the net's work), its margin filled by
replicating the border so that the canvas adds no edge of its own. The maps come back
by the inverse warp (bilinear) onto the input's pixels.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

#: (deg) edges nearer the horizontal than BLIND_DEG[0] or farther than BLIND_DEG[1] are turned
BLIND_DEG = (15.0, 70.0)
#: (deg) the turn
TURN_DEG = 45.0


def edge_angle(lines) -> float | None:
    """The mean image direction (deg, in (-90, 90], y down) of polar lines (N, 2)
    (rho px, theta rad), averaged as axes (doubled angles); None without a finite line."""
    lines = np.asarray(lines, float).reshape(-1, 2) if lines is not None else np.zeros((0, 2))
    th = lines[np.all(np.isfinite(lines), axis=1), 1]
    if not len(th):
        return None
    a2 = 2.0 * (th + math.pi / 2)
    a = 0.5 * math.degrees(math.atan2(float(np.sin(a2).sum()), float(np.cos(a2).sum())))
    return a if a > -90.0 else a + 180.0


def turn_for(lines, blind: tuple[float, float] = BLIND_DEG) -> float:
    """The turn (deg, OpenCV's sign) for an image whose shaft edges are predicted at
    ``lines`` (see the module doc): +-TURN_DEG in the blind zone, else 0."""
    a = edge_angle(lines)
    if a is None or blind[0] <= abs(a) <= blind[1]:
        return 0.0
    return TURN_DEG if a > 0 else -TURN_DEG


def turned(image: np.ndarray, deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(canvas, A): ``image`` turned by ``deg`` about its centre onto a canvas that holds
    all of it; A (2, 3) maps the image's pixels to the canvas's, p' = A [p; 1]."""
    h, w = image.shape[:2]
    c, s = abs(math.cos(math.radians(deg))), abs(math.sin(math.radians(deg)))
    W, H = int(math.ceil(w * c + h * s)), int(math.ceil(w * s + h * c))
    A = cv2.getRotationMatrix2D(((w - 1) / 2.0, (h - 1) / 2.0), deg, 1.0)
    A[:, 2] += ((W - 1) / 2.0 - (w - 1) / 2.0, (H - 1) / 2.0 - (h - 1) / 2.0)
    return cv2.warpAffine(image, A, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE), A


def turned_back(canvas_map: np.ndarray, A: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A map on the canvas of :func:`turned` (with its A) resampled onto the image's
    pixels (``shape`` = (h, w)), bilinear; 0 where the canvas does not reach."""
    h, w = shape
    return cv2.warpAffine(canvas_map, A, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)
