"""Overlay of a Detection (and optionally its Observation) on an undistorted frame.

Colours (BGR): all candidate segments thin grey; the detected shaft edges as
full lines across the image in yellow (0, 255, 255), with their segments
thicker; the observation's polar lines (when they differ from the edges, e.g.
RANSAC refits) in orange; its pixel sets as dots, one colour per edge id;
markers as green circles.
"""
from __future__ import annotations

import cv2
import numpy as np

from graphtrack.detect.base import Detection, Observation
from graphtrack.geometry.lines import line_in_image

GREY = (150, 150, 150)
YELLOW = (0, 255, 255)
ORANGE = (0, 140, 255)
GREEN = (0, 220, 0)
SET_COLOURS = ((255, 0, 255), (255, 255, 0), (0, 0, 255), (255, 128, 0))


def _bgr(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.ndim == 3 and img.shape[2] == 1:
        return cv2.cvtColor(img[:, :, 0], cv2.COLOR_GRAY2BGR)
    return np.ascontiguousarray(img[:, :, :3]).copy()


def _full_line(img: np.ndarray, rho: float, theta: float, colour, thickness: int = 1) -> None:
    """Draw cos(theta) x + sin(theta) y = rho clipped to the image."""
    if not (np.isfinite(rho) and np.isfinite(theta)):
        return
    ends = line_in_image(rho, theta, img.shape[1], img.shape[0])
    if ends is not None:
        a, b = (tuple(int(v) for v in np.round(e * 16)) for e in ends)   # 4 fractional bits
        cv2.line(img, a, b, colour, thickness, cv2.LINE_AA, 4)


def _segment(img, seg, colour, thickness=1) -> None:
    seg = np.asarray(seg, float)
    if not np.all(np.isfinite(seg)):
        return
    f = 16
    p = np.round(seg * f).astype(np.int64)
    p = np.clip(p, -(1 << 20), 1 << 20)
    cv2.line(img, (int(p[0]), int(p[1])), (int(p[2]), int(p[3])), colour, thickness, cv2.LINE_AA, 4)


def draw_detection(image: np.ndarray, detection: Detection,
                   observation: Observation | None = None) -> np.ndarray:
    """A BGR copy of ``image`` with the detection (and observation) drawn on it."""
    out = _bgr(image)
    h, w = out.shape[:2]
    for seg in np.asarray(detection.segments).reshape(-1, 4):
        _segment(out, seg, GREY, 1)
    for rho, theta in np.asarray(detection.shaft_lines).reshape(-1, 2):
        _full_line(out, rho, theta, YELLOW, 1)
    for seg in np.asarray(detection.shaft_segments).reshape(-1, 4):
        _segment(out, seg, YELLOW, 2)
    markers = detection.markers
    if observation is not None:
        ids = np.asarray(observation.edge_ids, int)
        for i, pts in enumerate(observation.pixels):
            p = np.round(np.asarray(pts, float).reshape(-1, 2)).astype(int)
            p = p[(p[:, 0] >= 0) & (p[:, 0] < w) & (p[:, 1] >= 0) & (p[:, 1] < h)]
            eid = int(ids[i]) if i < len(ids) else i
            out[p[:, 1], p[:, 0]] = SET_COLOURS[eid % len(SET_COLOURS)]
        if observation.model != "canny":
            for rho, theta in np.asarray(observation.lines).reshape(-1, 2):
                _full_line(out, rho, theta, ORANGE, 1)
        markers = observation.markers
    for x, y in np.asarray(markers, float).reshape(-1, 2):
        if np.isfinite(x) and np.isfinite(y):
            cv2.circle(out, (int(round(x * 16)), int(round(y * 16))), 8 * 16, GREEN, 2, cv2.LINE_AA, 4)
    return out
