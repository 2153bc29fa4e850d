"""Stereo tip metrics: the paper's 3-D tip error from triangulated labels, and the
2-D tip error in the right image.

Triangulation. A frame labelled in both images (labels.csv: raw left pixel u_L,
labels_right.csv: raw right pixel u_R) has its tip at the point X (LEFT camera
frame, metres) that ``cv2.triangulatePoints`` (linear, DLT) gives for the
UNDISTORTED label pixels and the projection matrices

    P_L = K1 [I | 0],        P_R = K2 [R | T]        (R, T: right-from-left, metres)

The 3-D tip error of a frame is |X_est - X| in mm, X_est = E_t . tip(q~_t) the
estimated tip in the left camera frame. A disparity error of d px between the two labels
moves X along its viewing ray by z^2 d / (f_x |T|) (:func:`disparity_depth_mm_per_px`; 7 mm
per px at 15 cm with f_x = 620 px and a 5 mm baseline), so with labels placed to a pixel
this figure is mostly the labels' own depth error; truth.csv's exact tip has none. It
depends on the labels and the rig's calibration only, so it scores a mono run (``--mono``)
on the same footing as a stereo one. The 2-D right error is |pi_R(X_est) - u_R| px in the
RAW right image (pi_R: right_T_left, K2, D2), as the left one is in the raw left image.
"""
from __future__ import annotations

import cv2
import numpy as np

from graphtrack.eval.metrics import summary


def triangulate(calibration, left_px: np.ndarray, right_px: np.ndarray) -> np.ndarray:
    """Raw left / right pixels (n, 2) of the same points -> (n, 3) LEFT-camera points (m)."""
    left_px = np.asarray(left_px, float).reshape(-1, 2)
    right_px = np.asarray(right_px, float).reshape(-1, 2)
    if len(left_px) == 0:
        return np.zeros((0, 3))
    ul = calibration.left.undistort_pixels(left_px)
    ur = calibration.right.undistort_pixels(right_px)
    P1 = calibration.left.K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = calibration.right.K @ np.hstack([np.asarray(calibration.R, float), np.ravel(calibration.T)[:, None]])
    X = cv2.triangulatePoints(P1, P2, ul.T.astype(np.float64), ur.T.astype(np.float64))
    return (X[:3] / X[3]).T


def triangulated_labels(calibration, labels: dict, labels_right: dict) -> dict[int, np.ndarray]:
    """{frame: (3,) left-camera tip (m)} for the frames labelled in both images."""
    both = sorted(set(labels) & set(labels_right))
    if not both:
        return {}
    X = triangulate(calibration, np.array([labels[f] for f in both]), np.array([labels_right[f] for f in both]))
    return {f: X[i] for i, f in enumerate(both) if np.all(np.isfinite(X[i]))}


def stereo_tip_metrics(calibration, frames, tips_3d: np.ndarray, labels: dict | None,
                       labels_right: dict | None) -> dict:
    """metrics.json's stereo tip keys for the tracked ``frames`` and their estimated
    left-camera tips ``tips_3d`` (F, 3) m (NaN where there is none):

    tip_error_right_px: summary of the raw right-image tip error (labels_right.csv);
    frames_scored_right; tip_error_3d_labels_mm: summary of |X_est - X| against the
    triangulated labels (labels.csv and labels_right.csv); frames_scored_3d_labels.
    Empty without a right camera or labels_right."""
    if calibration.right is None or not labels_right:
        return {}
    tips_3d = np.asarray(tips_3d, float).reshape(-1, 3)
    index = {int(f): i for i, f in enumerate(frames)}
    right_err = []
    for f, uv in sorted(labels_right.items()):
        i = index.get(int(f))
        if i is None or not np.all(np.isfinite(tips_3d[i])) or tips_3d[i][2] <= 0:
            continue
        right_err.append(float(np.linalg.norm(calibration.project_right(tips_3d[i]) - np.asarray(uv, float))))
    doc = {"tip_error_right_px": summary(np.array(right_err)), "frames_scored_right": len(right_err)}
    err3, depth = [], []
    for f, X in sorted(triangulated_labels(calibration, labels or {}, labels_right).items()):
        i = index.get(int(f))
        if i is not None and np.all(np.isfinite(tips_3d[i])):
            err3.append(1e3 * float(np.linalg.norm(tips_3d[i] - X)))
            depth.append(float(X[2]))
    doc.update({"tip_error_3d_labels_mm": summary(np.array(err3)), "frames_scored_3d_labels": len(err3)})
    if depth:
        doc["labels_3d_mm_per_px"] = disparity_depth_mm_per_px(calibration, float(np.median(depth)))
    return doc


def disparity_depth_mm_per_px(calibration, z: float) -> float:
    """How far (mm) one pixel of disparity error moves a triangulated point at depth z (m)
    along its viewing ray: dz = z^2 / (f_x |T|) per px (f_x: K1's, |T|: the baseline). Label
    noise enters the triangulated labels' 3-D error through it."""
    return float(1e3 * z * z / (calibration.left.K[0, 0] * np.linalg.norm(np.ravel(calibration.T))))
