"""Whether one frame can be tracked: the checks every frame passes before an estimator
sees it, from a recording (:meth:`graphtrack.io.recording.Recording.frames`) or built
by a caller (:meth:`graphtrack.track.Pipeline.step`).

:func:`frame_problem`: the left image's size against the calibration's ImageSize, its
format (8-bit BGR: a caller's 16-bit, float or grey array is refused, not left undetected), the
joint count against robot.json's DH joints, finite joints (and jaw, when the tool has
one), joints within a real arm's range (:mod:`graphtrack.io.joint_units`), and an
image whose bottom rows were cut off; a FrameError with the skip reason, or None.
:func:`right_problem`: why a right image is unusable (its size, or a copy of the left
image): that frame is updated from the left image alone.
"""
from __future__ import annotations

import numpy as np

from graphtrack.errors import FrameError
from graphtrack.geometry.camera import size_mismatch_hint
from graphtrack.io.joint_units import out_of_range


def frame_problem(frame, n_joints: int | None, size: tuple[int, int], bounds, has_jaw: bool) -> FrameError | None:
    """Why ``frame`` cannot be tracked (a FrameError naming the frame and the reason:
    ``image_size``, ``image_format``, ``joint_count``, ``nan_joints``, ``joint_range``, ``flat_image``), or
    None. ``size``: (height, width) of ImageSize; ``n_joints`` None: not checked;
    ``bounds``: |q| bounds per joint (None: the loose bound); ``has_jaw``: the jaw must be
    finite and within range too."""
    h, w = size
    image = None if frame.image is None else np.asarray(frame.image)
    numbers = np.asarray(frame.joints).dtype.kind in "iuf" and isinstance(frame.jaw, (int, float, np.number))
    if not numbers or isinstance(frame.jaw, bool):
        return FrameError(frame.index, "nan_joints", f"joint reading {frame.joints!r}, jaw {frame.jaw!r}: "
                          "not numbers (the jaw is NaN for a tool without a gripper)")
    joints, jaw = np.asarray(frame.joints, dtype=float).ravel(), float(frame.jaw)
    if image is None or image.ndim < 2 or image.shape[:2] != (h, w):
        got = "no image" if image is None else f"image is {image.shape[1]}x{image.shape[0]} px" if image.ndim >= 2 \
            else f"image has shape {image.shape}"
        hint = size_mismatch_hint(image.shape[:2], (h, w)) if image is not None and image.ndim >= 2 else ""
        return FrameError(frame.index, "image_size", f"{got}, camera_calibration.yaml ImageSize says {w}x{h}{hint}")
    if (why := image_format(image)) is not None:
        return FrameError(frame.index, "image_format", why)
    if np.ndim(frame.joints) != 1:
        return FrameError(frame.index, "joint_count", f"joint reading of shape {np.shape(frame.joints)}: "
                          "one reading is a flat vector of the DH joints")
    if n_joints is not None and joints.size != n_joints:
        jaw_hint = (": the jaw goes in Frame.jaw, not among the joints" if has_jaw and joints.size == n_joints + 1
                    else "")
        return FrameError(frame.index, "joint_count",
                          f"joint reading has {joints.size} values, robot.json has {n_joints} DH joints{jaw_hint}")
    if has_jaw and np.all(np.isfinite(joints)) and not np.isfinite(jaw):
        return FrameError(frame.index, "nan_joints", f"no jaw reading (jaw {jaw}): robot.json's tool has a gripper, so every "
                          "frame needs one (the jaw topic or joints.csv's jaw column; Frame.jaw in Python, rad)")
    if not np.all(np.isfinite(joints)):
        return FrameError(frame.index, "nan_joints", f"NaN/inf joint reading {joints.tolist()}, jaw {jaw}")
    if (why := out_of_range(joints, jaw, bounds, has_jaw)) is not None:
        return FrameError(frame.index, "joint_range", f"joint reading {why}")
    if (why := flat_image(image)) is not None:
        return FrameError(frame.index, "flat_image", why)
    return None


def image_format(image: np.ndarray) -> str | None:
    """Why ``image`` (of the right size) is not a frame's 8-bit BGR image (H x W x 3 uint8,
    what every reader decodes to), or None."""
    if image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3:
        return None
    if image.dtype != np.uint8:
        how = ("scale it to 0..255 first, e.g. (img >> 8).astype(np.uint8) for 16-bit, "
               "(img * 255).astype(np.uint8) for 0..1")
    elif image.ndim == 2 or image.shape[2] == 1:
        how = "convert it, e.g. cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)"
    else:
        how = "convert it to BGR, e.g. cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)"
    return f"image is {image.dtype} of shape {image.shape}, frames are 8-bit BGR (H x W x 3 uint8): {how}"


def right_problem(frame, size: tuple[int, int]) -> str | None:
    """Why the frame's right image is unusable (``image_size``: not ``size``;
    ``image_format``: not 8-bit BGR; ``same_as_left``: a copy of the left image), or None
    (also without a right image)."""
    right = frame.image_right
    if right is None:
        return None
    if right.ndim < 2 or right.shape[:2] != tuple(size):
        return "image_size"
    if image_format(right) is not None:
        return "image_format"
    return "same_as_left" if same_image(frame.image, right) else None


def same_image(a: np.ndarray, b: np.ndarray) -> bool:
    """True when two images that are not one flat colour are identical: a copy (a sparse
    grid first: different images differ there, so a stereo pair costs microseconds). Two
    flat frames (the light off) are alike without being copies."""
    if a.shape != b.shape or not np.array_equal(a[::16, ::16], b[::16, ::16]):
        return False
    return bool(np.array_equal(a, b)) and int(a.max()) != int(a.min())


def flat_image(image: np.ndarray) -> str | None:
    """Why an image is damaged, or None: its bottom quarter is one flat colour over whole
    rows while the rest is not (a JPEG cut off or zeroed mid-stream decodes with a flat
    grey tail; a JPEG zeroed whole does not decode at all). A sparse grid is tested first, so an
    ordinary frame costs microseconds."""
    h = image.shape[0] if image.ndim else 0
    tail = image[h - max(h // 4, 1):] if h else image
    sub = tail[::4, ::16]
    if sub.size and sub.min() != sub.max():
        return None
    if tail.size and tail.min() != tail.max():
        return None
    if image.size == 0 or image.min() == image.max():
        return None   # one flat colour all over: no damage signature (image-free estimators track it)
    return f"the bottom {len(tail)} rows are one flat colour (damaged or cut-off image data)"
