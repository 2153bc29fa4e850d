"""A calibration OpenCV's FileStorage saved (YAML, XML or JSON, also gzipped) under the
names its samples and most lab scripts use, into camera_calibration.yaml's contents.

``calibrateCamera`` / ``stereoCalibrate`` results are saved under names of the user's
choosing; a name is matched case- and underscore-blind against ``ALIASES`` (OpenCV's
stereo sample's ``M1 D1 M2 D2 R T``, its calibration sample's ``camera_matrix
distortion_coefficients image_width image_height``, the functions' own argument names
``cameraMatrix1 distCoeffs1 ...``), only among nodes of the role's size, or named with
``keys`` (role -> name). The roles: K1, D1 (or a single camera's K, D), K2, D2, R, T
(the right camera from the left: X_right = R X_left + T, in the unit the pattern's
square size was given in), and R1 (the left camera's rectification, if
``stereoRectify``'s result was saved). The image size: ``image_width`` and
``image_height``, else a two-number ``imageSize`` / ``image_size`` / ``ImageSize`` in
the order that centres the principal point (a ``cv::Size`` is [width, height],
graphtrack's ImageSize [height, width]), else given by the caller.

The left rectification R_1 (what turns a registration measured through the rectified
left image into the raw left frame) depends on R and T alone; it is computed with
``cv2.stereoRectify`` and a saved R1 must agree with it (a stale file, R1 and R2
swapped). A single camera's is the identity, as a ROS mono calibration's.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from graphtrack.errors import InputError
from graphtrack.geometry.camera import Calibration, Camera
from graphtrack.geometry.se3 import is_rotation, rotation_angle_deg

ALIASES = {
    "K1": ("k1", "m1", "cameramatrix1", "cameramatrixl", "cameramatrixleft", "leftcameramatrix", "mtxl",
           "mtxleft", "kl", "kleft"),
    "D1": ("d1", "distcoeffs1", "distcoeffsl", "distcoeffsleft", "leftdistcoeffs", "distl", "distleft", "dl",
           "dleft", "distortioncoefficientsleft"),
    "K2": ("k2", "m2", "cameramatrix2", "cameramatrixr", "cameramatrixright", "rightcameramatrix", "mtxr",
           "mtxright", "kr", "kright"),
    "D2": ("d2", "distcoeffs2", "distcoeffsr", "distcoeffsright", "rightdistcoeffs", "distr", "distright", "dr",
           "dright", "distortioncoefficientsright"),
    "K": ("cameramatrix", "k", "m", "mtx", "intrinsics"),
    "D": ("distortioncoefficients", "distcoeffs", "distcoeff", "d", "dist", "distortion"),
    "R": ("r", "rotation"),
    "T": ("t", "translation"),
    "R1": ("r1", "rectificationl", "rectificationleft"),
}
#: the number of values a role's node holds (D: any of DIST_SIZES)
SHAPES = {"K1": (9,), "K2": (9,), "K": (9,), "R": (9,), "R1": (9,), "T": (3,)}
#: OpenCV's plumb-bob family: k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tx ty]]]]
DIST_SIZES = (4, 5, 8, 12, 14)


def _norm(name: str) -> str:
    return name.lower().replace("_", "").replace("-", "")


def _one_line(e: BaseException) -> str:
    """OpenCV's own parser message (OpenCV 5 raises SystemError with it as the cause)."""
    e = e.__cause__ or e
    lines = [ln for ln in str(e).splitlines() if ln.strip()]
    text = lines[-1] if lines else type(e).__name__
    return text.split(" error: ", 1)[-1][:160]


def _nodes(path: Path, fs) -> dict[str, np.ndarray]:
    """The numeric root nodes of an open FileStorage: matrices, number sequences, numbers."""
    root = fs.root()
    if not root.isMap():
        raise InputError(f"{path}: holds no named nodes (an empty or non-mapping FileStorage)")
    out = {}
    for key in root.keys():
        node = root.getNode(key)
        if node.isMap():
            try:
                m = node.mat()
            except Exception:  # noqa: BLE001 - a nested struct, not a matrix: cv2 asserts
                m = None
            if m is not None:
                out[key] = np.asarray(m, float).ravel()
        elif node.isSeq():
            vals = [node.at(i) for i in range(node.size())]
            if vals and all(v.isReal() or v.isInt() for v in vals):
                out[key] = np.array([v.real() for v in vals])
        elif node.isReal() or node.isInt():
            out[key] = np.array([node.real()])
    return out


def read_storage(paths: list[str | Path]) -> dict[str, np.ndarray]:
    """Every numeric node at the root of the files, by name; a name in two files with
    different values is refused (two single-camera calibrations are not a stereo pair)."""
    import cv2

    nodes: dict[str, np.ndarray] = {}
    seen: dict[str, Path] = {}
    for path in map(Path, paths):
        if not path.is_file():
            raise InputError(f"{path}: file not found")
        try:
            fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
            if not fs.isOpened():
                raise InputError(f"{path}: not a file OpenCV's FileStorage reads")
            found = _nodes(path, fs)
            fs.release()
        except InputError:
            raise
        except Exception as e:  # noqa: BLE001 - OpenCV's parser raises cv2.error or SystemError
            raise InputError(f"{path}: not a file OpenCV's FileStorage reads ({_one_line(e)})") from None
        for k, v in found.items():
            if k in nodes and (nodes[k].shape != v.shape or not np.allclose(nodes[k], v)):
                raise InputError(f"{path}: node {k!r} is also in {seen[k]}, with other values: two cameras' own "
                                 "calibrations? give one stereo calibration (stereoCalibrate's K1 D1 K2 D2 R T)")
            nodes[k], seen[k] = v, path
    return nodes


def _fits(role: str, v: np.ndarray) -> bool:
    return v.size in (DIST_SIZES if role[0] == "D" else SHAPES[role])


def _find(nodes: dict[str, np.ndarray], role: str, keys: dict[str, str], where: str) -> np.ndarray | None:
    """The node playing ``role``: ``keys[role]`` if given (case- and underscore-blind; must
    exist and fit), else the one alias present among the nodes of the role's size."""
    by_norm = {_norm(k): k for k in nodes}
    if role in keys:
        name = by_norm.get(_norm(keys[role]))
        if name is None:
            raise InputError(f"{where}: no numeric node {keys[role]!r} (for {role}); it has: {', '.join(nodes)}")
        if not _fits(role, nodes[name]):
            raise InputError(f"{where}: {name!r} (given as {role}) has {nodes[name].size} values")
        return nodes[name]
    names = [by_norm[a] for a in ALIASES[role] if a in by_norm and _fits(role, nodes[by_norm[a]])]
    if len({tuple(nodes[n]) for n in names}) > 1:
        raise InputError(f"{where}: {', '.join(map(repr, names))} could each be {role} and differ: name one with "
                         f"--opencv-keys {role}=NAME")
    return nodes[names[0]] if names else None


def _size(nodes: dict[str, np.ndarray], size: tuple[int, int] | None, K: np.ndarray,
          where: str) -> tuple[int, int]:
    """(height, width) px of the file (module doc), or ``size`` when it holds none; a
    ``size`` that differs from the file's is refused (K belongs to the file's)."""
    by_norm = {_norm(k): v for k, v in nodes.items()}
    hw = None
    if "imagewidth" in by_norm and "imageheight" in by_norm:
        hw = (by_norm["imageheight"][0], by_norm["imagewidth"][0])
    elif by_norm.get("imagesize") is not None and by_norm["imagesize"].size == 2:
        a, b = by_norm["imagesize"]
        cx, cy = K[2], K[5]
        hw = (b, a) if abs(cx - a / 2) + abs(cy - b / 2) <= abs(cx - b / 2) + abs(cy - a / 2) else (a, b)
    if hw is None:
        if size is None:
            raise InputError(f"{where}: no image size (image_width and image_height, or imageSize): give "
                             "--image-size WIDTHxHEIGHT of the images it was calibrated on")
        return size
    if not all(float(x).is_integer() and 0 < x for x in hw):
        raise InputError(f"{where}: the image size {hw[1]:g} x {hw[0]:g} is not two positive integers")
    hw = (int(hw[0]), int(hw[1]))
    if size is not None and size != hw:
        raise InputError(f"{where}: calibrated on {hw[1]}x{hw[0]} images, not --image-size {size[1]}x{size[0]}; "
                         "K belongs to the calibration's size: scale it by hand, or record at that size")
    return hw


def calibration_from_opencv(paths: list[str | Path], keys: dict[str, str] | None = None,
                            size: tuple[int, int] | None = None,
                            unit_m: float | None = None) -> tuple[Calibration, np.ndarray]:
    """(Calibration, R_1) from FileStorage files (module doc). ``size``: (height, width)
    when the files hold none; ``unit_m``: metres per unit of T, required for a stereo
    pair (OpenCV's T is in the unit the square size was given in, which the file does not
    say). Calibration.T is in metres; R_1 the left rectification (identity for one camera)."""
    keys = dict(keys or {})
    unknown = set(keys) - set(ALIASES)
    if unknown:
        raise InputError(f"--opencv-keys: unknown role(s) {', '.join(sorted(unknown))} (roles: {', '.join(ALIASES)})")
    where = " and ".join(map(str, paths))
    nodes = read_storage(paths)
    fisheye = {_norm(k): v for k, v in nodes.items()}.get("fisheyemodel")
    if fisheye is not None and np.any(fisheye != 0):
        raise InputError(f"{where}: a fisheye calibration (fisheye_model): graphtrack's camera is OpenCV's plumb bob "
                         "(k1 k2 p1 p2 k3); calibrate with calibrateCamera's default model")
    K1, D1 = _find(nodes, "K1", keys, where), _find(nodes, "D1", keys, where)
    if K1 is None:
        K1, D1 = _find(nodes, "K", keys, where), _find(nodes, "D", keys, where)
    if K1 is None or D1 is None:
        raise InputError(f"{where}: no camera matrix and distortion found (names tried: M1/K1/cameraMatrix1, "
                         f"camera_matrix, ...; it has: {', '.join(nodes)}): name them with --opencv-keys K1=NAME,D1=NAME")
    h, w = _size(nodes, size, K1, where)
    left = _camera(K1, D1, h, w, where)
    stereo = {r: _find(nodes, r, keys, where) for r in ("K2", "D2", "R", "T")}
    if all(v is None for v in stereo.values()):
        return Calibration(left), np.eye(3)
    missing = [r for r, v in stereo.items() if v is None]
    if missing:
        raise InputError(f"{where}: a stereo calibration without {', '.join(missing)} (it has: {', '.join(nodes)}): "
                         "name them with --opencv-keys ROLE=NAME")
    if unit_m is None:
        raise InputError(f"{where}: OpenCV's T is in the unit the pattern's square size was given in, which the file "
                         "does not say: give --length-unit (m, mm, or metres per unit: OpenCV's stereo_calib sample "
                         "without -s is in squares, e.g. 0.0025 for 2.5 mm squares)")
    R = stereo["R"].reshape(3, 3)
    if not is_rotation(R):
        raise InputError(f"{where}: R is not a rotation matrix")
    calib = Calibration(left, _camera(stereo["K2"], stereo["D2"], h, w, where), R, stereo["T"] * unit_m)
    return calib, _rectification(calib, _find(nodes, "R1", keys, where), where)


def _rectification(calib: Calibration, saved: np.ndarray | None, where: str) -> np.ndarray:
    """R_1 of cv2.stereoRectify (it depends on R and T alone); a saved one must agree."""
    import cv2

    c1, c2 = calib.left, calib.right
    R1 = cv2.stereoRectify(c1.K, c1.dist, c2.K, c2.dist, (c1.width, c1.height), calib.R,
                           np.asarray(calib.T, float).reshape(3, 1))[0]
    if saved is None:
        return R1
    saved = saved.reshape(3, 3)
    if not is_rotation(saved):
        raise InputError(f"{where}: its R1 is not a rotation matrix")
    if not np.allclose(saved, R1, atol=1e-6):
        angle = rotation_angle_deg(R1, saved)
        raise InputError(f"{where}: its R1 is not stereoRectify's left rectification for its R and T ({angle:.2g} "
                         "deg apart; R1 and R2 swapped, or an older extrinsics file?)")
    return R1


def _camera(K: np.ndarray, D: np.ndarray, h: int, w: int, where: str) -> Camera:
    if D.size == 4:
        raise InputError(f"{where}: 4 distortion coefficients: a cv2.fisheye calibration (k1..k4)? graphtrack's "
                         "camera is OpenCV's plumb bob (calibrateCamera: k1 k2 p1 p2 k3)")
    if np.any(D[5:] != 0):
        raise InputError(f"{where}: distortion terms past k3 ({', '.join(f'{v:g}' for v in D[5:] if v)}; "
                         "CALIB_RATIONAL_MODEL, as OpenCV's stereo_calib sample uses, or thin prism / tilt): "
                         "graphtrack's camera is plumb bob: calibrate without those flags")
    return Camera(K.reshape(3, 3).copy(), D[:5].copy(), h, w)
