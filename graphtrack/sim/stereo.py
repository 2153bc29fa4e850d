"""The simulated right camera and the 2-D layers it sees (``graphtrack simulate --stereo``).

Rig. The right camera's centre sits ``baseline`` metres along the LEFT
camera's +x axis and is toed in by ``vergence`` radians (rotation about its y
axis, optical axis turned towards the left camera's), so the two optical
axes cross at Z = baseline / tan(vergence) in front of the rig. With R_r the
right camera's axes expressed in the left frame (R_r = RotY(-vergence)) and
C_r = (baseline, 0, 0):

    X_right = R X_left + T,   R = R_r^T,   T = -R_r^T C_r      (metres)

which is camera_calibration.yaml's right-from-left (R, T); the file stores T
in millimetres. Defaults: baseline 5 mm (a dVRK-like stereo endoscope),
vergence 2 deg (axes cross at ~14 cm, the middle of the tool's 8-18 cm),
K2 = K1 with cx + 0.4 % of the width and fx, fy x 1.003, D2 = D1 with k1
x 1.03: two slightly different but well-calibrated cameras.

2-D layers. The background and the tissue flaps are images drawn for the
LEFT raw view. The right view sees each as a fronto-parallel plane Z = depth
(left frame): a right raw pixel's ray (undistorted with K2, D2) is intersected
with the plane, the 3-D point projected into the left raw image, and the
layer sampled there (:func:`plane_map`, one ``cv2.remap`` table per depth).
The tool itself is ray-cast in 3-D by the right camera (exact silhouettes).
"""
from __future__ import annotations

import cv2
import numpy as np

from graphtrack.geometry.camera import Camera

BASELINE = 0.005          #: m
VERGENCE = np.radians(2.0)  #: rad


def rig(baseline: float = BASELINE, vergence: float = VERGENCE) -> tuple[np.ndarray, np.ndarray]:
    """Right-from-left (R 3x3, T (3,) metres) of the rig in the module doc."""
    c, s = np.cos(-vergence), np.sin(-vergence)
    R_r = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])   # RotY(-vergence)
    C_r = np.array([baseline, 0.0, 0.0])
    return R_r.T, -R_r.T @ C_r


def right_camera(left: Camera, rng=None) -> Camera:
    """K2, D2 of the module doc; with ``rng``, each offset is scaled by U(0, 2) instead."""
    g = (lambda: 1.0) if rng is None else (lambda: float(rng.uniform(0.0, 2.0)))
    K = left.K.copy()
    K[0, 2] += 0.004 * left.width * g()
    K[0, 0] *= 1.0 + 0.003 * g()
    K[1, 1] *= 1.0 + 0.003 * g()
    D = left.dist.copy()
    D[0] *= 1.0 + 0.03 * g()
    return Camera(K, D, left.height, left.width)


def to_right(R: np.ndarray, T: np.ndarray) -> np.ndarray:
    """4x4 right_T_left from (R, T metres)."""
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R, T
    return M


def plane_map(left: Camera, right: Camera, R: np.ndarray, T: np.ndarray, depth: float):
    """cv2.remap tables (float32 x, y) giving, per right raw pixel, the left raw pixel of
    the plane Z_left = depth seen through it (module doc)."""
    H, W = right.height, right.width
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    uv = np.stack([u.ravel(), v.ravel()], -1).reshape(-1, 1, 2)
    xy = cv2.undistortPoints(uv, right.K, right.dist,
                             criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-10)).reshape(-1, 2)
    d_r = np.concatenate([xy, np.ones((len(xy), 1))], 1)       # right-frame ray directions
    d_l = d_r @ R                                               # R^T d: left-frame directions
    c_l = -R.T @ T                                              # right centre in the left frame
    t = (depth - c_l[2]) / np.where(np.abs(d_l[:, 2]) > 1e-9, d_l[:, 2], 1e-9)
    P = c_l[None] + t[:, None] * d_l
    P[:, 2] = np.maximum(P[:, 2], 1e-6)
    uvl = left.project_raw(P).astype(np.float32)
    return uvl[:, 0].reshape(H, W), uvl[:, 1].reshape(H, W)


def warp(layer: np.ndarray, maps) -> np.ndarray:
    """A left-view layer (image or mask) as the right camera sees it (border reflected)."""
    return cv2.remap(layer, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
