"""A lab's calibration files as the dVRK's tools write them, into camera_calibration.yaml
and handeye.yaml.

**ROS camera_info YAML** (``camera_calibration``'s ``ost.yaml``, or ``left.yaml`` and
``right.yaml`` of a stereo calibration; the ``camera_calibration_parsers`` layout):
``image_width``, ``image_height``, ``camera_matrix``, ``distortion_model``,
``distortion_coefficients``, ``rectification_matrix`` R_i, ``projection_matrix`` P_i,
lengths in the calibration's unit (metres by ROS convention); or the same fields of the
first ``sensor_msgs/CameraInfo`` message on a bag's left (and right) camera_info topic,
which a ROS camera driver publishes from that calibration. R_i turns camera i's
frame into the rectified frame, and P_2 = K' [I | t] projects a point of the LEFT
rectified frame into the right rectified image (t_x = -baseline for a horizontal pair,
t_y for a vertical one, t_z = P_2[2,3], 0 in ROS), so

    X_right = R_2^T (R_1 X_left + t):   R = R_2^T R_1,  T = R_2^T t.

A recording of the *rectified* images (``image_rect`` topics) is described by the
rectified cameras instead: K_i = P_i[:, :3], no distortion, R = I, T = t.

**dVRK camera registration** (``dvrk_camera_registration``'s
``PSMx-registration-open-cv.json``): ``{"base-frame": {"reference-frame": ..., "transform":
4x4}}``, the PSM base frame in the camera's OpenCV frame, metres. The registration
measures the camera through the rectified left image (its projection matrix, no
distortion), so the transform maps into the left *rectified* frame; for raw images
the left camera's own frame is camera_T_base = [R_1^T 0; 0 1] . transform.

Every function raises InputError naming the file and the field.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphtrack.errors import InputError, is_number, number_list, one_line, read_json, read_yaml
from graphtrack.geometry.camera import Calibration, Camera
from graphtrack.geometry.se3 import is_rigid, is_rotation
from graphtrack.io.bag import open_bag
from graphtrack.io.recording import is_ros2_bag

#: the distortion models graphtrack's camera (OpenCV's plumb bob) represents
PLUMB_BOB = ("plumb_bob", "rational_polynomial")
UNITS_M = {"m": 1.0, "mm": 1e-3}


@dataclass
class RosCamera:
    """One ROS camera_info YAML: raw intrinsics K, distortion D (5), rectification R (3x3),
    projection P (3x4; None when the file's is all zero), image height and width (px)."""

    K: np.ndarray
    D: np.ndarray
    R: np.ndarray
    P: np.ndarray | None
    height: int
    width: int
    path: Path


def _field(doc: dict, key: str, n: int, path: Path) -> np.ndarray:
    """doc[key]["data"] (or a plain list): n finite numbers (any number when n is 0)."""
    return number_list(doc, key, path, (n,) if n else (), noun="field",
                       missing=" (a ROS camera_info YAML has camera_matrix, distortion_coefficients, "
                               "rectification_matrix and projection_matrix)")


def read_ros_camera(path: str | Path) -> RosCamera:
    """Read one ROS camera_info YAML (module doc)."""
    path = Path(path)
    doc = read_yaml(path)
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a ROS camera_info YAML (image_width, camera_matrix, ...)")
    return _ros_camera(doc, path)


def _ros_camera(doc: dict, path: Path) -> RosCamera:
    """A camera_info mapping (the YAML's layout) -> RosCamera; ``path`` names it in errors.
    As ROS's image_geometry reads it: no distortion coefficients is no distortion, an
    all-zero rectification is the identity, an all-zero projection is none (P None:
    a raw mono camera needs none)."""
    size = [doc.get("image_height"), doc.get("image_width")]
    if not all(is_number(s) and float(s).is_integer() and s > 0 for s in size):
        raise InputError(f"{path}: fields 'image_width' and 'image_height' must be positive integers")
    model = str(doc.get("distortion_model") or "plumb_bob")
    if model not in PLUMB_BOB:
        raise InputError(f"{path}: distortion_model '{model}' is not supported: graphtrack's camera is "
                         "OpenCV's plumb bob (k1 k2 p1 p2 k3); calibrate with that model")
    K = _field(doc, "camera_matrix", 9, path).reshape(3, 3)
    if not np.any(K):
        raise InputError(f"{path}: camera_matrix is all zero: the camera was not calibrated when this was written")
    D = _field(doc, "distortion_coefficients", 0, path)
    if D.size not in (0, 4, 5, 8):
        raise InputError(f"{path}: distortion_coefficients has {D.size} values; plumb bob's are k1 k2 p1 p2 [k3]")
    if np.any(D[5:] != 0):
        raise InputError(f"{path}: distortion_coefficients: the rational model's k4 k5 k6 "
                         f"({', '.join(f'{v:g}' for v in D[5:])}) are not supported (graphtrack's camera is "
                         "k1 k2 p1 p2 k3)")
    D5 = np.zeros(5)
    D5[: min(5, D.size)] = D[:5]
    R = _field(doc, "rectification_matrix", 9, path).reshape(3, 3)
    R = np.eye(3) if not np.any(R) else R
    if not is_rotation(R):
        raise InputError(f"{path}: field 'rectification_matrix' is not a rotation matrix")
    P = _field(doc, "projection_matrix", 12, path).reshape(3, 4)
    if not np.any(P):
        P = None
    elif not (P[0, 0] > 0 and P[1, 1] > 0):
        raise InputError(f"{path}: field 'projection_matrix' has no positive focal lengths")
    return RosCamera(K, D5, R, P, int(size[0]), int(size[1]), path)


CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"


def _camera_info_topics(infos: list[str], chosen: list[str] | None, where: str) -> list[str]:
    """The left (and right) camera_info topics: ``chosen``, else the bag's only one, else
    the one with ``left`` and the one with ``right`` in its name."""
    if not infos:
        raise InputError(f"{where}: no camera_info messages ({CAMERA_INFO_TYPE}) in the bag: give the "
                         "calibration's YAMLs with --ros")
    if chosen:
        for t in chosen:
            if t not in infos:
                raise InputError(f"{where}: no {CAMERA_INFO_TYPE} topic {t} (it has: {', '.join(infos)})")
        return list(chosen)
    if len(infos) == 1:
        return infos
    left = [t for t in infos if "left" in t.lower()]
    right = [t for t in infos if "right" in t.lower()]
    if len(left) == 1 and len(right) <= 1:
        return left + right
    raise InputError(f"{where}: {len(infos)} {CAMERA_INFO_TYPE} topics ({', '.join(infos)}) and no "
                     "single left one: name the left (and right) one with --camera-info-topic")


def _bag_path(path: Path) -> Path:
    """A ROS 1 .bag file, a ROS 2 bag folder, or a recording folder holding one of them."""
    if not path.exists():
        raise InputError(f"{path}: no such bag")
    if path.is_file() or is_ros2_bag(path):
        return path
    found = sorted(path.glob("*.bag")) + sorted(p for p in path.iterdir() if is_ros2_bag(p))
    if len(found) != 1:
        raise InputError(f"{path}: a folder that is no ROS 2 bag (no metadata.yaml) and holds "
                         f"{len(found)} bags: give the bag itself")
    return found[0]


def read_bag_cameras(path: str | Path, topics: list[str] | None = None) -> tuple[list[RosCamera], list[str]]:
    """The first CameraInfo message of the left (and right) camera_info topic of a ROS 1
    bag or ROS 2 bag folder (or a recording folder holding one), as :func:`read_ros_camera`
    reads a YAML (ROS 1 fields K, D, R, P; ROS 2 k, d, r, p), and the topics read."""
    path = _bag_path(Path(path))
    try:
        with open_bag(path) as r:
            infos = [n for n, c in r.topics.items() if c.msgtype == CAMERA_INFO_TYPE and c.msgcount]
            chosen = _camera_info_topics(infos, topics, str(path))
            cams = []
            for topic in chosen:
                conn = [c for c in r.connections if c.topic == topic]
                _, _, raw = next(r.messages(connections=conn))
                cams.append(_from_message(r.deserialize(raw, CAMERA_INFO_TYPE), f"{path} ({topic})"))
            return cams, chosen
    except InputError:
        raise
    except Exception as e:  # noqa: BLE001 - rosbags raises many types on damaged or foreign files
        raise InputError(f"{path}: cannot read the bag's camera_info ({one_line(e)})") from None


def _from_message(msg, where: str) -> RosCamera:
    """A CameraInfo message -> the YAML layout -> :func:`_ros_camera`. K, D, R, P describe
    the full unbinned sensor; a binned or cropped (ROI) image is refused."""
    def field(name):
        v = getattr(msg, name, None)
        return getattr(msg, name.lower()) if v is None else v

    w, h = int(msg.width), int(msg.height)
    bx, by = int(getattr(msg, "binning_x", 0) or 0), int(getattr(msg, "binning_y", 0) or 0)
    roi = getattr(msg, "roi", None)
    cropped = roi is not None and roi.width and roi.height and (
        roi.x_offset, roi.y_offset, roi.width, roi.height) != (0, 0, w, h)
    if max(bx, by) > 1 or cropped:
        raise InputError(f"{where}: the camera publishes binned or cropped images (binning {bx}x{by}, ROI "
                         f"{roi.width}x{roi.height} at {roi.x_offset},{roi.y_offset}); its calibration describes "
                         "the full sensor: record the full images, or write camera_calibration.yaml for the "
                         "published ones by hand")
    doc = {"image_width": w, "image_height": h, "distortion_model": str(msg.distortion_model or "plumb_bob"),
           "camera_matrix": [float(x) for x in field("K")],
           "distortion_coefficients": [float(x) for x in field("D")],
           "rectification_matrix": [float(x) for x in field("R")],
           "projection_matrix": [float(x) for x in field("P")]}
    return _ros_camera(doc, Path(where))


def _projection(cam: RosCamera, why: str) -> np.ndarray:
    if cam.P is None:
        raise InputError(f"{cam.path}: projection_matrix is all zero; {why} needs it")
    return cam.P


def _baseline(cam: RosCamera, why: str) -> np.ndarray:
    """t: the camera's offset from the first camera in the rectified frame, from P =
    K' [I | t] (P[:, 3] = K' t): t_z = P[2,3], t_x = (P[0,3] - c_x' t_z) / f_x',
    t_y = (P[1,3] - c_y' t_z) / f_y'. Entries under 1e-9 of the focal length are 0."""
    P = _projection(cam, why)
    col = np.where(np.abs(P[:, 3]) > 1e-9 * P[0, 0], P[:, 3], 0.0)
    tz = col[2]
    return np.array([(col[0] - P[0, 2] * tz) / P[0, 0], (col[1] - P[1, 2] * tz) / P[1, 1], tz])


def calibration_from_ros(left: RosCamera, right: RosCamera | None = None, rectified: bool = False,
                         unit_m: float = 1.0) -> Calibration:
    """camera_calibration.yaml's contents from ROS camera_info YAMLs (module doc): the raw
    cameras (K, D; R = R_2^T R_1, T = R_2^T t), or with ``rectified`` the rectified ones.
    ``unit_m``: metres per unit of the calibration's lengths. Calibration.T is in metres.
    The left camera's projection must hold no baseline (else it is a right camera's)."""
    def camera(c: RosCamera) -> Camera:
        if rectified:
            return Camera(_projection(c, "--rectified")[:, :3].copy(), np.zeros(5), left.height, left.width)
        return Camera(c.K.copy(), c.D.copy(), left.height, left.width)

    if left.P is not None and np.any(_baseline(left, "") != 0):
        raise InputError(f"{left.path}: its projection_matrix holds a baseline (P[:, 3] not 0): it is a "
                         "right (second) camera's; give the left camera's first")
    if right is None:
        return Calibration(camera(left))
    if (right.height, right.width) != (left.height, left.width):
        raise InputError(f"{right.path}: image size {right.width}x{right.height} differs from {left.path}'s "
                         f"{left.width}x{left.height}; both cameras of a recording share ImageSize")
    _projection(left, "a stereo pair")
    t = _baseline(right, "a stereo pair") * unit_m
    if not np.any(t != 0):
        raise InputError(f"{right.path}: its projection_matrix holds no baseline (P[:, 3] = 0): "
                         "not the right camera of a stereo calibration")
    if rectified:
        return Calibration(camera(left), camera(right), np.eye(3), t)
    return Calibration(camera(left), camera(right), right.R.T @ left.R, right.R.T @ t)


@dataclass
class Registration:
    """A dVRK camera registration: ``transform`` camera-from-base (4x4, metres) and the
    camera frame it names (``reference_frame``, "" when none)."""

    transform: np.ndarray
    reference_frame: str


def read_dvrk_registration(path: str | Path, unit: str = "m") -> Registration:
    """The camera-from-base transform (metres) of a dVRK camera registration JSON
    (``{"base-frame": {"transform": 4x4}}``, module doc). Its ``-dVRK.json`` twin (the
    dVRK's camera axes, x and y turned) is refused."""
    path = Path(path)
    if re.search(r"registration-dvrk\.json$", path.name, re.IGNORECASE):
        raise InputError(f"{path}: the registration in the dVRK's camera axes (x and y turned); give its twin "
                         f"{re.sub('(?i)-dvrk[.]json$', '-open-cv.json', path.name)}, in OpenCV's axes")
    doc = read_json(path)
    frame = doc.get("base-frame") if isinstance(doc, dict) else None
    M = frame.get("transform") if isinstance(frame, dict) else None
    if M is None:
        raise InputError(f"{path}: missing 'base-frame' -> 'transform' (a dVRK camera registration's "
                         "PSMx-registration-open-cv.json)")
    if (not isinstance(M, list) or len(M) != 4
            or not all(isinstance(r, list) and len(r) == 4 and all(is_number(x) for x in r) for r in M)):
        raise InputError(f"{path}: 'base-frame' -> 'transform' must be a 4x4 list of numbers")
    T = np.asarray(M, dtype=float)
    if not is_rigid(T):
        raise InputError(f"{path}: 'base-frame' -> 'transform' is not a rigid transform (a rotation, a "
                         "translation, last row 0 0 0 1)")
    T[:3, 3] *= UNITS_M[unit]
    return Registration(T, str(frame.get("reference-frame") or ""))


def arm_of(path: str | Path) -> str | None:
    """PSM1, PSM2 or PSM3 when the file's name starts with it (``PSM2-registration-open-cv.json``)."""
    m = re.match(r"(PSM[123])(?![0-9])", Path(path).name, re.IGNORECASE)
    return m.group(1).upper() if m else None


def handeye_to_raw(camera_T_base: np.ndarray, R1: np.ndarray) -> np.ndarray:
    """A transform into the left rectified frame -> into the left camera's own (raw) frame:
    [R_1^T 0; 0 1] . camera_T_base, R_1 the left camera's rectification."""
    C = np.eye(4)
    C[:3, :3] = np.asarray(R1, float).T
    return C @ camera_T_base
