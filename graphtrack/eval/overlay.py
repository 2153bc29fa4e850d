"""overlay.mp4: what the tracker saw and what it concluded, drawn on the RAW images.

Per frame (BGR colours):
- green: the tool skeleton (robot.json's skeleton_structure) placed with the
  estimated E and the joint readings, projected WITH distortion;
- yellow: the detected shaft edges (lines through the whole image) and, thicker,
  the associated shaft segments;
- cyan dots (2 px radius): the observation's pixel sets (E_e / E_l) of the pixel models;
- magenta circles: detected marker centroids; magenta tick across the shaft: its
  detected end (:mod:`graphtrack.detect.shaft_end`);
- red ring: the estimated tool tip, drawn over the white cross of the labelled tip
  (labels.csv), so that both show where they coincide;
- the caption (frame number; "left" / "right" in a stereo video, "refined" for poses
  refined after the run), white on a dark band, legible on a white bench.

Detections live in UNDISTORTED pixels; everything is mapped to raw pixels with
:meth:`graphtrack.geometry.camera.Camera.distort_pixels`, lines as polylines
sampled along them (a straight undistorted line is curved in the raw image).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np

from graphtrack.detect.base import Detection, Observation
from graphtrack.estimate.base import Estimate
from graphtrack.geometry.lines import line_in_image
from graphtrack.io.video import StampedVideoWriter, open_video
from graphtrack.robot.features import base_features

GREEN = (0, 200, 0)
YELLOW = (0, 255, 255)
CYAN = (255, 255, 0)
MAGENTA = (255, 0, 255)
RED = (0, 0, 255)
WHITE = (255, 255, 255)


def _pts(uv: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(uv, float) * 16).astype(np.int32)  # 4 fractional bits


def sample_segment(a: np.ndarray, b: np.ndarray, n: int = 24) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n)[:, None]
    return (1 - t) * np.asarray(a, float) + t * np.asarray(b, float)


def draw_polyline_raw(img: np.ndarray, camera, uv_undistorted: np.ndarray, color, thickness: int = 1) -> None:
    """Draw a polyline given in undistorted pixels onto the raw image."""
    raw = camera.distort_pixels(uv_undistorted)
    raw = raw[np.all(np.isfinite(raw), axis=1)]
    if len(raw) >= 2:
        cv2.polylines(img, [_pts(raw).reshape(-1, 1, 2)], False, color, thickness, cv2.LINE_AA, 4)


def draw_cross(img, uv, color, size: int = 6, thickness: int = 1) -> None:
    if uv is None or not np.all(np.isfinite(uv)):
        return
    u, v = float(uv[0]), float(uv[1])
    for a, b in (((u - size, v - size), (u + size, v + size)), ((u - size, v + size), (u + size, v - size))):
        cv2.line(img, tuple(_pts(a)), tuple(_pts(b)), color, thickness, cv2.LINE_AA, 4)


def draw_overlay(image: np.ndarray, ctx, q: np.ndarray, E: np.ndarray, detection=None, observation=None,
                 tip_uv: np.ndarray | None = None, label_uv: np.ndarray | None = None,
                 text: str | None = None) -> np.ndarray:
    """Return a copy of the raw BGR image with the overlay of one frame drawn on it."""
    cam = ctx.camera
    img = np.ascontiguousarray(image.copy() if image is not None
                               else np.zeros((cam.height, cam.width, 3), np.uint8))
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    h, w = img.shape[:2]
    # skeleton through E and the readings, projected with distortion
    if E is not None and np.all(np.isfinite(E)):
        feats = base_features(ctx.robot, q).transformed(E)
        for seg in np.asarray(feats.skeleton).reshape(-1, 2, 3):
            pts3 = sample_segment(seg[0], seg[1], 16)
            if np.any(pts3[:, 2] <= 1e-6):
                continue
            raw = cam.project_raw(pts3)
            if np.all(np.isfinite(raw)):
                cv2.polylines(img, [_pts(raw).reshape(-1, 1, 2)], False, GREEN, 2, cv2.LINE_AA, 4)
    if detection is not None:
        for rho, theta in np.asarray(detection.shaft_lines, float).reshape(-1, 2):
            ends = line_in_image(rho, theta, w, h, margin=0.05 * max(w, h))
            if ends is not None:
                draw_polyline_raw(img, cam, sample_segment(ends[0], ends[1], 48), YELLOW, 1)
        for x1, y1, x2, y2 in np.asarray(detection.shaft_segments, float).reshape(-1, 4):
            draw_polyline_raw(img, cam, sample_segment((x1, y1), (x2, y2), 16), YELLOW, 3)
    if observation is not None:
        for pix in observation.pixels or []:
            pix = np.asarray(pix, float).reshape(-1, 2)
            if len(pix):
                for u, v in _pts(cam.distort_pixels(pix)) // 16:
                    if 0 <= u < w and 0 <= v < h:
                        cv2.circle(img, (int(u), int(v)), 2, CYAN, -1)
    if observation is not None:
        for x, y, dx, dy in np.asarray(observation.shaft_end, float).reshape(-1, 4):   # a tick across the shaft
            n = 12.0 * np.array([-dy, dx])
            draw_polyline_raw(img, cam, sample_segment(np.array([x, y]) - n, np.array([x, y]) + n, 8), MAGENTA, 2)
    markers = None
    if detection is not None and len(detection.markers):
        markers = detection.markers
    elif observation is not None and len(observation.markers):
        markers = observation.markers
    if markers is not None:
        for uv in cam.distort_pixels(np.asarray(markers, float).reshape(-1, 2)):
            if np.all(np.isfinite(uv)):
                cv2.circle(img, tuple(_pts(uv)), 6 * 16, MAGENTA, 2, cv2.LINE_AA, 4)
    if label_uv is not None:
        draw_cross(img, label_uv, WHITE, 7, 2)
    if tip_uv is not None and np.all(np.isfinite(tip_uv)):
        cv2.circle(img, tuple(_pts(tip_uv)), 5 * 16, RED, 2, cv2.LINE_AA, 4)
    if text:
        draw_caption(img, text)
    return img


def draw_caption(img: np.ndarray, text: str) -> None:
    """``text`` at the top left, white on a dark band (legible on any background)."""
    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
    x0, y0, x1, y1 = 4, 20 - th - 4, min(img.shape[1], 12 + tw), min(img.shape[0], 20 + base + 2)
    img[max(0, y0):y1, x0:x1] = (img[max(0, y0):y1, x0:x1] * 0.35).astype(np.uint8)
    cv2.putText(img, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, WHITE, 1, cv2.LINE_AA)


class OverlayWriter:
    """Stream overlay frames into an mp4 at the camera's raw size and the recording's frame rate
    (:class:`graphtrack.io.video.StampedVideoWriter`; ``fps`` fixes it instead).

    ``write(frame, estimate, detection, observation, tip_uv_raw)`` per tracked
    frame; ``close()`` at the end (also a context manager). ``frames_written``
    counts the frames.

    Stereo (``ctx.stereo``): each video frame is left | right side by side (twice
    the width), the right panel drawn through the right camera (right_T_left . E,
    K2, D2) with the right image's ``right`` = (Detection, Observation) and
    ``labels_right``; a frame without a usable right image has a black right panel
    that says so (metrics.json's ``right_skipped_reasons`` count why).
    """

    def __init__(self, path: str | Path, ctx, labels: dict | None = None, fps: float | None = None,
                 title: str | None = None, labels_right: dict | None = None):
        self.path = Path(path)
        self.ctx = ctx
        self.labels = labels or {}
        self.labels_right = labels_right or {}
        self.right_ctx = dataclasses.replace(ctx, camera=ctx.right) if ctx.stereo else None
        self.title = title
        self._video = StampedVideoWriter(self.path, fps)

    @property
    def fps(self) -> float | None:
        """The video's frame rate (None until the first frames have fixed it)."""
        return self._video.fps

    @property
    def frames_written(self) -> int:
        return self._video.frames_received

    def write(self, frame, estimate: Estimate | None, detection: Detection | None = None,
              observation: Observation | None = None, tip_uv_raw=None, right=(None, None)) -> None:
        E = None if estimate is None else estimate.E
        label = self.labels.get(int(frame.index))
        text = f"frame {frame.index}" + ("  left" if self.right_ctx is not None else "") + \
            (f"  {self.title}" if self.title else "")
        img = draw_overlay(frame.image, self.ctx, frame.q, E, detection, observation, tip_uv_raw, label, text)
        if self.right_ctx is not None:
            img = np.hstack([img, self._right_panel(frame, E, right, img.shape)])
        self._video.write(img, frame.stamp)

    def _right_panel(self, frame, E, right, shape) -> np.ndarray:
        """The right image's overlay (black without the right image), resized to ``shape``."""
        if frame.image_right is None:
            img = np.zeros(shape, np.uint8)
            draw_caption(img, "right: no usable right image in this frame")
            return img
        Er = None if E is None else self.ctx.right_T_left @ E
        tip = None
        feats = base_features(self.ctx.robot, frame.q)
        if Er is not None and feats.tip is not None:
            p = feats.transformed(Er).tip
            tip = self.right_ctx.camera.project_raw(p) if p[2] > 0 else None
        img = draw_overlay(frame.image_right, self.right_ctx, frame.q, Er, right[0], right[1], tip,
                           self.labels_right.get(int(frame.index)), "right" + (f"  {self.title}" if self.title else ""))
        return img if img.shape == shape else cv2.resize(img, (shape[1], shape[0]))

    def close(self) -> None:
        self._video.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def video_frame_count(path: str | Path) -> int:
    """Frames in a video, by decoding it (reliable for mp4v files OpenCV wrote)."""
    cap = open_video(path)
    n = 0
    try:
        while True:
            ok, _ = cap.read()
            if not ok:
                break
            n += 1
    finally:
        cap.release()
    return n
