"""handeye.yaml: the nominal camera-from-base transform of one arm.

The file stores (format doc, "handeye.yaml")::

    PSM1_tvec: [tx, ty, tz]    # MILLIMETRES
    PSM1_rvec: [rx, ry, rz]    # axis-angle, radians (OpenCV Rodrigues vector)

and maps points in the PSM base (remote-centre-of-motion) frame into the left
camera frame. In memory the transform is a 4x4 matrix in METRES, like every
other length in graphtrack.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from graphtrack.errors import InputError, number_list, read_yaml
from graphtrack.geometry.se3 import bw_to_matrix, is_rigid, matrix_to_bw
from graphtrack.io.topics import ARMS, TopicSelection, handeye_arm


def _read_yaml(path: Path) -> dict:
    doc = read_yaml(path)
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a mapping of keys like 'PSM1_tvec'")
    return doc


#: plausibility bounds: the camera is between MIN_TRANSLATION_MM and MAX_TRANSLATION_MM
#: from the arm's base (its remote centre of motion, where the arm's port is: the
#: endoscope enters through another port), and a Rodrigues vector's angle is at most 2 pi
MIN_TRANSLATION_MM = 1.0
MAX_TRANSLATION_MM = 5000.0
MAX_ROTATION_RAD = 2 * np.pi


def load_handeye(path: str | Path, arm: str | None = None) -> np.ndarray:
    """Read handeye.yaml -> 4x4 camera-from-base transform in metres.

    Parameters
    ----------
    path : the YAML file (translation in mm, rotation as axis-angle in rad).
    arm : key prefix (``PSM2`` -> ``PSM2_tvec`` / ``PSM2_rvec``); the keys must exist.
        None: the file's only arm (:func:`graphtrack.io.topics.handeye_arm`), else PSM1.

    Returns
    -------
    (4, 4) float array, translation in METRES.

    Raises
    ------
    InputError naming the file and the key when a key is missing, is not three
    numbers, holds NaN/inf, puts the camera more than 5 m or less than 1 mm (a
    translation in metres) from the base, turns more
    than 2 pi, or when the file holds several arms and none was named.
    """
    path = Path(path)
    doc = _read_yaml(path)
    prefix = handeye_arm(doc, TopicSelection(arm=arm), str(path))
    if f"{prefix}_tvec" not in doc:
        found = sorted(k[: -len("_tvec")] for k in doc if isinstance(k, str) and k.endswith("_tvec"))
        others = f"keys for {', '.join(found)} only" if found else "no *_tvec key"
        rename = (f"; if the calibration is of {prefix}, rename {found[0]}_tvec and {found[0]}_rvec to "
                  f"{prefix}_tvec and {prefix}_rvec" if len(found) == 1 and found[0].upper() in ARMS else
                  f" (an arm's: {', '.join(ARMS)}; an ECM's or another device's registration is another "
                  "transform)")
        raise InputError(f"{path}: missing key '{prefix}_tvec': the arm tracked is {prefix} (--arm, or the "
                         f"arm whose joints the recording carries) and the file has {others}; the keys' "
                         f"prefix names the arm the calibration is of{rename}")
    t_mm = number_list(doc, f"{prefix}_tvec", path, (3,))
    rvec = number_list(doc, f"{prefix}_rvec", path)
    if rvec.size != 3:
        matrix = " (a rotation matrix? cv2.Rodrigues turns one into this vector)" if rvec.size == 9 else ""
        raise InputError(f"{path}: key '{prefix}_rvec' has {rvec.size} values, expected 3: an axis-angle "
                         f"(Rodrigues) vector, radians{matrix}")
    with np.errstate(over="ignore"):     # a value near 1e308: its norm is inf, refused below
        t_norm, angle = float(np.linalg.norm(t_mm)), float(np.linalg.norm(rvec))
    if not t_norm <= MAX_TRANSLATION_MM:
        raise InputError(f"{path}: key '{prefix}_tvec' is {t_norm:.4g} mm from the base; "
                         f"expected at most {MAX_TRANSLATION_MM:g} mm (the file is in millimetres)")
    if not t_norm >= MIN_TRANSLATION_MM:
        raise InputError(f"{path}: key '{prefix}_tvec' puts the camera {t_norm:.3g} mm from the "
                         f"arm's base (remote centre of motion); expected at least {MIN_TRANSLATION_MM:g} mm "
                         "(the file is in millimetres: values in metres must be multiplied by 1000)")
    if not angle <= MAX_ROTATION_RAD:
        raise InputError(f"{path}: key '{prefix}_rvec' turns {angle:.4g} rad; an axis-angle "
                         "vector's angle is at most 2 pi")
    return bw_to_matrix(np.concatenate([t_mm / 1000.0, rvec]))


def save_handeye(path: str | Path, T: np.ndarray, arm: str = "PSM1") -> None:
    """Write a 4x4 camera-from-base transform (metres) as handeye.yaml (mm, rad).

    InputError naming the file and key, writing nothing, for what :func:`load_handeye`
    would refuse to read back: T not a finite rigid 4x4 transform (a rotation, last row
    0 0 0 1), or its translation outside MIN_TRANSLATION_MM..MAX_TRANSLATION_MM once in mm
    (a T in mm, or in m but almost 0)."""
    T = np.asarray(T, dtype=float)
    if not is_rigid(T):
        raise InputError(f"{path}: T is not a finite rigid 4x4 transform (a rotation, a translation, last row "
                         f"0 0 0 1): {np.array2string(T, precision=4)}")
    mm = 1000.0 * float(np.linalg.norm(T[:3, 3]))
    if not MIN_TRANSLATION_MM <= mm <= MAX_TRANSLATION_MM:
        raise InputError(f"{path}: key '{arm}_tvec' would put the camera {mm:.4g} mm from the base, expected "
                         f"{MIN_TRANSLATION_MM:g} to {MAX_TRANSLATION_MM:g} mm (T's translation is in metres)")
    bw = matrix_to_bw(T)
    doc = {f"{arm}_tvec": [float(v) * 1000.0 for v in bw[:3]],
           f"{arm}_rvec": [float(v) for v in bw[3:]]}
    Path(path).write_text(yaml.safe_dump(doc, default_flow_style=None, sort_keys=False))
