"""A calibration OpenCV's FileStorage saved (YAML, XML or JSON) under the names its
samples and most lab scripts use, into camera_calibration.yaml's contents.

``calibrateCamera`` / ``stereoCalibrate`` results are saved under names of the user's
choosing; a name is matched case- and underscore-blind against ``ALIASES`` (OpenCV's
stereo sample's ``M1 D1 M2 D2 R T [R1 P1 ...]``, its calibration sample's
``camera_matrix distortion_coefficients image_width image_height``, the functions'
own argument names ``cameraMatrix1 distCoeffs1 ...``), or named with ``keys``
(role -> name). The roles: K1, D1 (or a mono file's K, D), K2, D2, R, T (the right
camera from the left: X_right = R X_left + T, in the pattern's unit), and R1 (the
left camera's rectification, when ``stereoRectify``'s result was saved too: the
frame a registration made through the rectified image is in). The image size: given
by the caller, else ``image_width`` and ``image_height``, else a two-number
``imageSize`` / ``image_size`` / ``ImageSize`` in the order that centres the principal
point (a ``cv::Size`` is [width, height], graphtrack's ImageSize [height, width]).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from graphtrack.errors import InputError, read_text
from graphtrack.geometry.camera import Calibration, Camera

ALIASES = {
    "K1": ("k1", "m1", "cameramatrix1", "cameramatrixl", "cameramatrixleft", "leftcameramatrix", "mtxl", "kl",
           "kleft"),
    "D1": ("d1", "distcoeffs1", "distcoeffsl", "distcoeffsleft", "leftdistcoeffs", "distl", "dl", "dleft",
           "distortioncoefficientsleft"),
    "K2": ("k2", "m2", "cameramatrix2", "cameramatrixr", "cameramatrixright", "rightcameramatrix", "mtxr", "kr",
           "kright"),
    "D2": ("d2", "distcoeffs2", "distcoeffsr", "distcoeffsright", "rightdistcoeffs", "distr", "dr", "dright",
           "distortioncoefficientsright"),
    "K": ("cameramatrix", "k", "m", "mtx", "intrinsics"),
    "D": ("distortioncoefficients", "distcoeffs", "d", "dist", "distortion"),
    "R": ("r", "rotation"),
    "T": ("t", "translation"),
    "R1": ("r1", "rectificationl", "rectificationleft"),
}
SHAPES = {"K1": 9, "K2": 9, "K": 9, "R": 9, "R1": 9, "T": 3, "D1": 0, "D2": 0, "D": 0}


def _norm(name: str) -> str:
    return name.lower().replace("_", "").replace("-", "")


def read_storage(paths: list[str | Path]) -> dict[str, np.ndarray]:
    """Every numeric node at the root of the files (later files win): matrices, number
    sequences and numbers, as float arrays, by their names."""
    import cv2

    nodes: dict[str, np.ndarray] = {}
    for path in map(Path, paths):
        read_text(path)     # a missing, unreadable or binary file is named before OpenCV prints its own
        try:
            fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
            ok = fs.isOpened()
        except Exception as e:  # noqa: BLE001 - OpenCV's parser raises cv2.error or SystemError
            raise InputError(f"{path}: not a file OpenCV's FileStorage reads ({str(e).splitlines()[-1][:80]})") from None
        if not ok:
            raise InputError(f"{path}: not a file OpenCV's FileStorage reads")
        root = fs.root()
        for key in root.keys():
            node = root.getNode(key)
            if node.isMap():
                m = node.mat()
                if m is not None:
                    nodes[key] = np.asarray(m, float).ravel()
            elif node.isSeq():
                vals = [node.at(i) for i in range(node.size())]
                if vals and all(v.isReal() or v.isInt() for v in vals):
                    nodes[key] = np.array([v.real() for v in vals])
            elif node.isReal() or node.isInt():
                nodes[key] = np.array([node.real()])
        fs.release()
    return nodes


def _find(nodes: dict[str, np.ndarray], role: str, keys: dict[str, str], where: str) -> np.ndarray | None:
    """The node playing ``role``: ``keys[role]`` if given (must exist), else the first alias present."""
    if role in keys:
        if keys[role] not in nodes:
            raise InputError(f"{where}: no numeric node {keys[role]!r} (for {role}); it has: {', '.join(nodes)}")
        name = keys[role]
    else:
        by_norm = {_norm(k): k for k in nodes}
        name = next((by_norm[a] for a in ALIASES[role] if a in by_norm), None)
        if name is None:
            return None
    v = nodes[name]
    n = SHAPES[role]
    if n and v.size != n:
        raise InputError(f"{where}: {name!r} (taken as {role}) has {v.size} values, expected {n}")
    return v


def _size(nodes: dict[str, np.ndarray], size: tuple[int, int] | None, K: np.ndarray,
          where: str) -> tuple[int, int]:
    """(height, width) px: ``size`` if given, else image_width / image_height, else a
    two-number size node (imageSize, image_size, ImageSize), whose order (OpenCV writes a
    cv::Size as [width, height], graphtrack's ImageSize is [height, width]) is the one
    that puts K's principal point nearer the image's centre."""
    if size is not None:
        return size
    by_norm = {_norm(k): v for k, v in nodes.items()}
    if "imagewidth" in by_norm and "imageheight" in by_norm:
        w, h = by_norm["imagewidth"][0], by_norm["imageheight"][0]
    elif by_norm.get("imagesize") is not None and by_norm["imagesize"].size == 2:
        a, b = by_norm["imagesize"]
        cx, cy = K[2], K[5]
        w, h = (a, b) if abs(cx - a / 2) + abs(cy - b / 2) <= abs(cx - b / 2) + abs(cy - a / 2) else (b, a)
    else:
        raise InputError(f"{where}: no image size (image_width and image_height, or imageSize): give --image-size "
                         "WIDTHxHEIGHT of the recorded images")
    if not (float(w).is_integer() and float(h).is_integer() and w > 0 and h > 0):
        raise InputError(f"{where}: the image size {w:g} x {h:g} is not two positive integers")
    return int(h), int(w)


def calibration_from_opencv(paths: list[str | Path], keys: dict[str, str] | None = None,
                            size: tuple[int, int] | None = None,
                            unit_m: float | None = None) -> tuple[Calibration, np.ndarray | None]:
    """(Calibration, R1 or None) from FileStorage files (module doc). ``size``: (height,
    width) when the files hold none; ``unit_m``: metres per unit of T, required for a
    stereo pair (OpenCV's T is in the calibration pattern's unit, which the file does not
    say). Calibration.T is in metres."""
    keys = dict(keys or {})
    unknown = set(keys) - set(ALIASES)
    if unknown:
        raise InputError(f"--opencv-keys: unknown role(s) {', '.join(sorted(unknown))} (roles: {', '.join(ALIASES)})")
    where = " and ".join(map(str, paths))
    nodes = read_storage(paths)
    K1 = _find(nodes, "K1", keys, where)
    D1 = _find(nodes, "D1", keys, where)
    if K1 is None:
        K1, D1 = _find(nodes, "K", keys, where), _find(nodes, "D", keys, where)
    if K1 is None or D1 is None:
        raise InputError(f"{where}: no camera matrix and distortion found (names tried: M1/K1/cameraMatrix1, "
                         f"camera_matrix, ...; it has: {', '.join(nodes)}): name them with --opencv-keys K1=NAME,D1=NAME")
    h, w = _size(nodes, size, K1, where)
    stereo = {r: _find(nodes, r, keys, where) for r in ("K2", "D2", "R", "T")}
    left = _camera(K1, D1, h, w, where)
    if all(v is None for v in stereo.values()):
        return Calibration(left), None
    missing = [r for r, v in stereo.items() if v is None]
    if missing:
        raise InputError(f"{where}: a stereo calibration without {', '.join(missing)} (it has: {', '.join(nodes)}): "
                         "name them with --opencv-keys ROLE=NAME")
    if unit_m is None:
        raise InputError(f"{where}: OpenCV's T is in the unit of the calibration pattern's squares, which the file "
                         "does not say: give --length-unit m or mm")
    R1 = _find(nodes, "R1", keys, where)
    right = _camera(stereo["K2"], stereo["D2"], h, w, where)
    return Calibration(left, right, stereo["R"].reshape(3, 3), stereo["T"] * unit_m), \
        (None if R1 is None else R1.reshape(3, 3))


def _camera(K: np.ndarray, D: np.ndarray, h: int, w: int, where: str) -> Camera:
    if D.size not in (0, 4, 5, 8, 12, 14) or np.any(D[5:] != 0):
        raise InputError(f"{where}: distortion of {D.size} values with nonzero terms past k3: graphtrack's camera "
                         "is OpenCV's plumb bob (k1 k2 p1 p2 k3)")
    D5 = np.zeros(5)
    D5[: min(5, D.size)] = D[:5]
    return Camera(K.reshape(3, 3).copy(), D5, h, w)
