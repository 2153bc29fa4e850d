"""Notes for the user on a recording whose parts look inconsistent but may be right:
labels of frames it does not have, right images without a right camera, a baseline
with the right camera on the left, a principal point far off centre, focal lengths
far apart. Warnings, never refusals: a rig wired or cropped unusually, with every file
consistent, tracks correctly (docs/decisions/plausible-inputs.md)."""
from __future__ import annotations

import numpy as np

from graphtrack.io.folder import FolderSource


def consistency_notes(rec) -> list[str]:
    """Lines for the user on a recording's parts that look wrong or will not be used (module
    doc): the calibration's own notes (a dropped skew), jaw readings a jawless robot ignores,
    labels of frames the recording does not have, right images without the right camera's
    calibration, a suspicious baseline, principal point or focal-length ratio."""
    notes = list(rec.calibration.notes)
    if rec.has_jaw and not rec.uses_jaw:
        notes.append(f"{rec.path}: the recording has jaw readings but {rec.path / 'robot.json'} has no "
                     "has_gripper: the jaw is ignored (a tool with jaws needs \"has_gripper\": true, or its tip "
                     "is placed as if they were closed)")
    for name, labels in (("labels.csv", rec.labels), ("labels_right.csv", rec.labels_right)):
        beyond = sorted(k for k in (labels or {}) if k >= len(rec))
        if beyond:
            from_one = min(labels) == 1 and beyond[-1] == len(rec)   # 1..n for frames 0..n-1
            notes.append(f"{rec.path / name}: {len(beyond)} labels of frames the recording does not have "
                         f"(it has {len(rec)} frames; first: frame {beyond[0]}); they are not scored"
                         + ("; numbered from 1? frames are numbered from 0, as in joints.csv, so each of the "
                            "others is scored against the frame after its own" if from_one else ""))
    if rec.has_right_images and rec.calibration.right is None:
        notes.append(f"{rec.path}: right images but no K2, D2, R, T in camera_calibration.yaml; "
                     "tracking the left image only")
    if rec.labels_right is not None and not rec.calibration.stereo:   # scored through the right camera alone
        notes.append(f"{rec.path / 'labels_right.csv'}: not scored: camera_calibration.yaml has no right "
                     "camera (K2, D2, R, T)")
    notes += calibration_notes(rec.calibration, rec.path / "camera_calibration.yaml")
    right_dir = rec.path / "frames_right"
    if isinstance(rec.source, FolderSource) and right_dir.exists() and not right_dir.is_dir():
        notes.append(f"{right_dir}: not a folder, so the recording has no right images; "
                     "tracking the left image only")
    return notes


#: a stereo baseline shorter than this (mm) is noted: no stereo endoscope's is (T in cm?)
SHORT_BASELINE_MM = 2.0


def calibration_notes(calib, path) -> list[str]:
    """Lines on a camera calibration (``path``: its camera_calibration.yaml) that looks wrong
    but may be right: a baseline with the right camera on the left or under 2 mm, a principal point far
    off centre, focal lengths far apart. ``graphtrack calibration`` prints them as it writes
    the file, ``track`` as it reads it."""
    notes = []
    if calib.stereo and left_of_left(calib.T):
        t_mm = np.round(1e3 * np.ravel(calib.T), 2).tolist()
        notes.append(f"{path}: T = {t_mm} mm puts the right camera to the left "
                     "of the left one (X_right = R X_left + T has T_x < 0 for a right camera on the right): "
                     "are T's sign or the left and right images swapped?")
    if calib.stereo and 1e3 * np.linalg.norm(calib.T) < SHORT_BASELINE_MM:
        notes.append(f"{path}: T's length is {1e3 * np.linalg.norm(calib.T):.3g} mm, under {SHORT_BASELINE_MM:g} mm: "
                     "a stereo endoscope's baseline is 3 to 6 mm (the dVRK's about 5): T in cm, or calibrated "
                     "with the square size in another unit? (tracking trusts the baseline for depth)")
    for key, cam in (("K1", calib.left), ("K2", calib.right)):
        if cam is not None and off_centre(cam):
            notes.append(f"{path}: {key}'s principal point "
                         f"({cam.K[0, 2]:.0f}, {cam.K[1, 2]:.0f}) px lies outside the middle half of the "
                         f"{cam.width}x{cam.height} image: a calibration of another image size?")
        if cam is not None and not 0.8 <= cam.K[0, 0] / cam.K[1, 1] <= 1.25:
            notes.append(f"{path}: {key}'s focal lengths fx = {cam.K[0, 0]:g}, "
                         f"fy = {cam.K[1, 1]:g} px differ by a factor {cam.K[0, 0] / cam.K[1, 1]:.2g}: pixels "
                         "that are not square (interlaced fields), or a K of another image size in one direction?")
    return notes


def left_of_left(T) -> bool:
    """True when a mostly horizontal baseline T (right-from-left, |T_x| the largest
    component) has T_x > 0: the "right" camera sits left of the left one."""
    t = np.ravel(T).astype(float)
    return bool(t.size == 3 and abs(t[0]) >= np.abs(t[1:]).max() and t[0] > 0)


def off_centre(cam) -> bool:
    """True when the camera's principal point lies outside the middle half of its image
    (|cx - w/2| > w/4 or |cy - h/2| > h/4): endoscope optics centre it within a few
    per cent, and K scaled for another resolution puts it there."""
    cx, cy = float(cam.K[0, 2]), float(cam.K[1, 2])
    return abs(cx - cam.width / 2) > cam.width / 4 or abs(cy - cam.height / 2) > cam.height / 4
