"""Pinhole camera with OpenCV's plumb-bob distortion, and camera_calibration.yaml.

Projection of a point X = (X, Y, Z) in the camera frame (metres):

    x = X / Z,  y = Y / Z                               (unit camera)
    r^2 = x^2 + y^2
    x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)
    y_d = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y
    raw pixel         = (fx x_d + cx, fy y_d + cy)
    undistorted pixel = (fx x + cx,   fy y + cy)

"Undistorted pixels" are the pixels of the undistorted image, which keeps the
same K (``cv2.initUndistortRectifyMap(K, D, None, K, ...)``); every detector
and every line (rho, theta) lives there.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml

from graphtrack.errors import InputError, is_number, number_list, read_yaml
from graphtrack.geometry.image_scale import scale_points
from graphtrack.geometry.se3 import is_rotation


@dataclass
class Camera:
    """K: 3x3 intrinsics (px); dist: (k1, k2, p1, p2, k3); image size in px."""

    K: np.ndarray
    dist: np.ndarray
    height: int
    width: int
    _maps: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def diagonal(self) -> float:
        """Image diagonal (px), the unit of the method's % errors."""
        return float(np.hypot(self.height, self.width))

    # -- projection -----------------------------------------------------------------
    def _distort_xy(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x_d, y_d) of unit-camera coordinates x, y (the module doc's plumb-bob model)."""
        d = np.ravel(self.dist)
        k1, k2, p1, p2, k3 = (float(d[i]) if i < d.size else 0.0 for i in range(5))
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return xd, yd

    def distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        """Apply plumb-bob distortion to unit-camera coordinates (..., 2)."""
        xy = np.asarray(xy, float)
        return np.stack(self._distort_xy(xy[..., 0], xy[..., 1]), -1)

    def normalized_to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """Normalised image coordinates (..., 2) (X/Z, Y/Z, no distortion) -> undistorted pixels (u, v)
        = (fx x + cx, fy y + cy) px."""
        xy = np.asarray(xy, float)
        return np.stack([self.fx * xy[..., 0] + self.cx, self.fy * xy[..., 1] + self.cy], -1)

    def pixels_to_normalized(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted pixels (..., 2) px -> normalised image coordinates ((u - cx)/fx, (v - cy)/fy)."""
        uv = np.asarray(uv, float)
        return np.stack([(uv[..., 0] - self.cx) / self.fx, (uv[..., 1] - self.cy) / self.fy], -1)

    def in_image(self, points: np.ndarray, tol_px: float = 1.0) -> np.ndarray:
        """(...) bool: which camera-frame points (..., 3) this camera images: in front (Z > 0),
        their raw pixel inside the image, and that pixel's ray their own.

        The plumb-bob polynomial is not monotonic far off the axis (with k1 < 0 and
        nothing else, x_d = x (1 + k1 r^2) turns back at r = 1 / sqrt(-3 k1)), so a point
        far outside the field of view can have a raw pixel inside the image. Undistorting
        that pixel (OpenCV's iterative inverse, :meth:`undistort_pixels`) then gives the
        ray of a point near the axis; such a point, more than ``tol_px`` undistorted px
        from its own projection, is not imaged."""
        p = np.asarray(points, float)
        shape, p = p.shape[:-1], p.reshape(-1, 3)
        out = np.zeros(len(p), bool)
        front = np.flatnonzero(p[:, 2] > 0)
        raw = self.project_raw(p[front])
        inside = (raw[:, 0] >= 0) & (raw[:, 0] <= self.width - 1) & (raw[:, 1] >= 0) & (raw[:, 1] <= self.height - 1)
        idx, raw = front[inside], raw[inside]
        if len(idx) and np.any(np.ravel(self.dist)):
            back = self.undistort_pixels(raw)
            idx = idx[np.hypot(*(back - self.project_undistorted(p[idx])).T) <= tol_px]
        out[idx] = True
        return out.reshape(shape)

    def project_undistorted(self, points: np.ndarray) -> np.ndarray:
        """Camera-frame points (..., 3) -> undistorted pixels (..., 2)."""
        p = np.asarray(points, float)
        return self.normalized_to_pixels(p[..., :2] / p[..., 2:3])

    def project_raw(self, points: np.ndarray) -> np.ndarray:
        """Camera-frame points (..., 3) -> raw (distorted) pixels (..., 2)."""
        p = np.asarray(points, float)
        return self.normalized_to_pixels(self.distort_normalized(p[..., :2] / p[..., 2:3]))

    def distort_pixels(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted pixels (..., 2) -> raw pixels (..., 2) (in one pass: the detectors
        call it per edge and per profile)."""
        uv = np.asarray(uv, float)
        fx, fy, cx, cy = float(self.K[0, 0]), float(self.K[1, 1]), float(self.K[0, 2]), float(self.K[1, 2])
        xd, yd = self._distort_xy((uv[..., 0] - cx) / fx, (uv[..., 1] - cy) / fy)
        out = np.empty(uv.shape[:-1] + (2,))
        out[..., 0] = fx * xd + cx
        out[..., 1] = fy * yd + cy
        return out

    def undistort_pixels(self, uv: np.ndarray) -> np.ndarray:
        """Raw pixels (N, 2) -> undistorted pixels (N, 2) (OpenCV's iterative inverse)."""
        uv = np.asarray(uv, float).reshape(-1, 1, 2)
        if len(uv) == 0:
            return np.zeros((0, 2))
        out = cv2.undistortPoints(uv, self.K, self.dist, P=self.K,
                                  criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12))
        return out.reshape(-1, 2)

    # -- images ---------------------------------------------------------------------
    def undistort_maps(self, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Remap tables raw -> undistorted, computed once per camera and scale.

        With ``scale`` s != 1 the output is the undistorted image of the camera
        ``self.scaled(s)`` sampled straight from the FULL-size raw image: one
        remap does the resize and the undistortion, at the cost of the output size.
        """
        if scale not in self._maps:
            out = self if scale == 1.0 else self.scaled(scale)
            self._maps[scale] = cv2.initUndistortRectifyMap(
                self.K, self.dist, None, out.K, (out.width, out.height), cv2.CV_16SC2)
        return self._maps[scale]

    def undistort(self, image: np.ndarray, scale: float = 1.0) -> np.ndarray:
        """Raw image -> undistorted image (bilinear), of ``self.scaled(scale)``'s size and K.
        ValueError unless ``image`` is this camera's size (height x width)."""
        hw = tuple(np.shape(image)[:2])
        if np.ndim(image) not in (2, 3) or hw != (self.height, self.width):
            hint = size_mismatch_hint(hw, (self.height, self.width)) if len(hw) == 2 else ""
            raise ValueError(f"image of shape {np.shape(image)} (height, width[, channels]); the camera's "
                             f"is {self.height} x {self.width}{hint}")
        m1, m2 = self.undistort_maps(scale)
        return cv2.remap(image, m1, m2, cv2.INTER_LINEAR)

    def undistort_resized(self, image: np.ndarray) -> np.ndarray:
        """This camera's raw image already resized (cv2.resize) to h x w -> the
        undistorted image of ``self.scaled(s)`` (s = w / width), remap tables cached per size.

        Resize-then-undistort: the remap runs at the reduced size (a 4x reduction costs
        1/16 of undistorting the full image); an undistortion-free camera (D = 0, a
        rectified pair) returns the image as it is."""
        h, w = image.shape[:2]
        if not np.any(np.ravel(self.dist)):
            return image
        key = ("resized", h, w)
        if key not in self._maps:
            small = self.scaled(w / float(self.width))
            self._maps[key] = cv2.initUndistortRectifyMap(
                small.K, small.dist, None, small.K, (w, h), cv2.CV_16SC2)
        m1, m2 = self._maps[key]
        return cv2.remap(image, m1, m2, cv2.INTER_LINEAR)

    def scaled(self, s: float) -> "Camera":
        """The same camera for images resized by factor s (K scaled, distortion kept)."""
        K = self.K.copy()
        K[0, 0] *= s
        K[1, 1] *= s
        K[:2, 2] = scale_points(K[:2, 2], s)
        return Camera(K, self.dist.copy(), int(round(self.height * s)), int(round(self.width * s)))


@dataclass
class Calibration:
    """camera_calibration.yaml: the left camera, and the right one for stereo.

    R: right-from-left rotation; T: right-from-left translation in METRES
    (converted from the file's millimetres).
    """

    left: Camera
    right: Camera | None = None
    R: np.ndarray | None = None
    T: np.ndarray | None = None
    #: lines for the user on what reading the file changed (a skew dropped)
    notes: list[str] = field(default_factory=list)

    @property
    def stereo(self) -> bool:
        return self.right is not None

    @property
    def right_T_left(self) -> np.ndarray:
        """4x4 right-from-left transform (metres): X_right = R X_left + T."""
        if self.right is None:
            raise ValueError("mono calibration: no right camera")
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = self.R, np.ravel(self.T)
        return M

    def project_right(self, points_left: np.ndarray, raw: bool = True) -> np.ndarray:
        """LEFT-camera-frame points (..., 3) m -> right image pixels (..., 2): raw
        (distorted with D2) or undistorted (K2 only)."""
        p = np.asarray(points_left, float) @ np.asarray(self.R).T + np.ravel(self.T)
        return self.right.project_raw(p) if raw else self.right.project_undistorted(p)

    def undistort_right(self, image: np.ndarray, scale: float = 1.0) -> np.ndarray:
        """Raw right image -> undistorted right image (K2 kept; see Camera.undistort)."""
        return self.right.undistort(image, scale)


def size_mismatch_hint(image_hw, calib_hw) -> str:
    """Why an image of (height, width) ``image_hw`` may not match ImageSize ``calib_hw``:
    its sides swapped, or the same shape at another scale (K scales with the image)."""
    if tuple(image_hw) == tuple(calib_hw)[::-1]:
        return " (width and height swapped there?)"
    s = image_hw[1] / calib_hw[1]
    if max(abs(int(a) - int(b)) for a, b in zip(image_hw, calib_hw)) <= max(8, 0.02 * max(calib_hw)):
        return " (a few pixels off: cropped or padded images? the calibration must be of the images as recorded)"
    if image_hw[0] < 2 or abs(image_hw[0] / calib_hw[0] - s) > 2.0 / calib_hw[0]:
        return ""
    return (f" (the same shape at {s:g} times the size: calibrated at another resolution? scale ImageSize and "
            f"K's fx, fy, cx, cy by {s:g})")


#: largest image side accepted in ImageSize (px)
MAX_IMAGE_SIDE = 20000


def _matrix(doc: dict, key: str, n: int, path: Path) -> np.ndarray:
    """doc[key] (or doc[key]["data"]): a flat list of n finite numbers (D: 4, 5 or 8)."""
    if key.startswith("D"):
        a = number_list(doc, key, path)
        if a.size not in (4, 5, 8):
            raise InputError(f"{path}: key '{key}' has {a.size} values, expected 4, 5 or 8 "
                             "(OpenCV's k1 k2 p1 p2 [k3 [k4 k5 k6]])")
        return a
    return number_list(doc, key, path, (n,))


def _image_size(doc: dict, path: Path) -> tuple[int, int]:
    size = doc.get("ImageSize")
    if isinstance(size, dict):   # an OpenCV-style mapping, as the matrices may be
        size = size.get("data")
    if (not isinstance(size, list) or len(size) != 2
            or not all(is_number(x) and float(x).is_integer() and 0 < x <= MAX_IMAGE_SIDE for x in size)):
        raise InputError(f"{path}: ImageSize must be [height, width], two integers in "
                         f"1..{MAX_IMAGE_SIDE}, got {str(size)[:60]}")
    return int(size[0]), int(size[1])


#: the shortest focal length accepted, as a fraction of the image's longer side: a
#: pinhole camera with f = 0.05 w sees 2 atan(10) = 169 deg across (endoscopes: 60-90 deg)
MIN_FOCAL_FRACTION = 0.05


#: px, the most a dropped skew may move the image's top or bottom rows (more is refused)
MAX_SKEW_SHIFT_PX = 3.0


def _intrinsics(doc: dict, key: str, h: int, w: int, path: Path, notes: list | None = None) -> np.ndarray:
    """K: focal lengths in [1, 1e6] px and at least MIN_FOCAL_FRACTION of the image's
    longer side, principal point within one image size of the image, last row (0, 0, 1),
    K[1, 0] = 0, and a skew K[0, 1] that, dropped (the camera has none), moves the image's
    top and bottom rows by at most MAX_SKEW_SHIFT_PX (over half a pixel: a line in ``notes``)."""
    K = _matrix(doc, key, 9, path).reshape(3, 3)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if not (0 < fx <= 1e6 and 0 < fy <= 1e6):
        raise InputError(f"{path}: key '{key}': focal lengths must be in [1, 1e6] px, got {fx:g}, {fy:g}")
    if min(fx, fy) < max(1.0, MIN_FOCAL_FRACTION * max(w, h)):
        raise InputError(f"{path}: key '{key}': focal lengths {fx:g}, {fy:g} px would see more than 168 deg "
                         f"across the {w}x{h} image; K is in pixels (a K divided by the image size, as some "
                         "tools store it, must be multiplied back)")
    if not (-w <= cx <= 2 * w and -h <= cy <= 2 * h):
        raise InputError(f"{path}: key '{key}': principal point ({cx:g}, {cy:g}) is far outside the "
                         f"{w}x{h} image")
    if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise InputError(f"{path}: key '{key}' is not an intrinsic matrix (last row must be 0 0 1, "
                         "K[1,0] = 0)")
    shift = abs(K[0, 1]) * (h / 2) / fy   # px: dropping the skew moves the image's top and bottom rows by this
    if shift > MAX_SKEW_SHIFT_PX:
        raise InputError(f"{path}: key '{key}': skew K[0,1] = {K[0, 1]:g} px is not supported: graphtrack's "
                         "camera is OpenCV's, without skew, and dropping it would move the image's top and "
                         f"bottom rows by {shift:.3g} px; calibrate without it (OpenCV never estimates it; "
                         "MATLAB: EstimateSkew false)")
    if shift > 0.5 and notes is not None:
        notes.append(f"{path}: {key}'s skew K[0,1] = {K[0, 1]:g} px is dropped (graphtrack's camera has none): "
                     f"the image's top and bottom rows move by up to {shift:.2g} px; calibrate without it")
    K = K.copy()
    K[0, 1] = 0.0
    return K


#: the shortest stereo baseline accepted (mm): stereo endoscopes' are 3-6 mm; shorter is
#: a baseline written in metres, or none
MIN_BASELINE_MM = 0.5


def load_calibration(path: str | Path) -> Calibration:
    """Read camera_calibration.yaml (format doc); raise InputError naming file and key."""
    path = Path(path)
    doc = read_yaml(path)
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a mapping of keys")
    h, w = _image_size(doc, path)
    notes: list[str] = []

    def cam(kk: str, dk: str) -> Camera:
        K = _intrinsics(doc, kk, h, w, path, notes)
        D = _matrix(doc, dk, 5, path)
        if np.any(np.abs(D) > 1e4):
            raise InputError(f"{path}: key '{dk}' holds a coefficient beyond 1e4")
        if np.any(D[5:] != 0):
            raise InputError(f"{path}: key '{dk}': the rational model's k4 k5 k6 ({', '.join(f'{v:g}' for v in D[5:])}) "
                             "are not supported: graphtrack's camera model is k1 k2 p1 p2 k3 (give 5 values, or "
                             "k4 k5 k6 = 0)")
        D5 = np.zeros(5)
        D5[: min(5, D.size)] = D[:5]
        return Camera(K, D5, h, w)

    left = cam("K1", "D1")
    if any(k in doc for k in ("K2", "D2", "R", "T")):   # one stereo key: all four are needed
        right = cam("K2", "D2")
        R = _matrix(doc, "R", 9, path).reshape(3, 3)
        if not is_rotation(R):
            raise InputError(f"{path}: key 'R' is not a rotation matrix (right-from-left, row-major)")
        T = _matrix(doc, "T", 3, path) / 1000.0
        if not MIN_BASELINE_MM <= 1e3 * np.linalg.norm(T) <= 1000.0:
            mm = 1e3 * np.linalg.norm(T)
            unit = ("values in metres must be multiplied by 1000" if mm < 0.05 else
                    "values in centimetres by 10, in metres by 1000" if mm < MIN_BASELINE_MM else
                    "is it in micrometres or pixels?")
            raise InputError(f"{path}: key 'T' is {mm:.3g} mm long; a stereo baseline is {MIN_BASELINE_MM:g} to "
                             f"1000 mm (the dVRK endoscope's about 5 mm), in millimetres: {unit}")
        return Calibration(left, right, R, T, notes)
    return Calibration(left, notes=notes)


def save_calibration(path: str | Path, calib: Calibration) -> None:
    """Write camera_calibration.yaml in the format doc's layout (T in mm)."""
    cam = calib.left
    doc = {"ImageSize": [int(cam.height), int(cam.width)],
           "K1": {"data": [float(v) for v in cam.K.ravel()]},
           "D1": {"data": [float(v) for v in cam.dist.ravel()]}}
    if calib.right is not None:
        doc["K2"] = {"data": [float(v) for v in calib.right.K.ravel()]}
        doc["D2"] = {"data": [float(v) for v in calib.right.dist.ravel()]}
        doc["R"] = {"data": [float(v) for v in np.asarray(calib.R).ravel()]}
        doc["T"] = [float(v) * 1000.0 for v in np.asarray(calib.T).ravel()]
    Path(path).write_text(yaml.safe_dump(doc, default_flow_style=None, sort_keys=False))
