"""Stereo recordings in: right images matched by stamp (bag, folder), raw and rectified
pairs, missing / corrupt right frames, the right camera's projection."""
import json
from pathlib import Path
from types import SimpleNamespace as NS

import cv2
import numpy as np
import pytest

from graphtrack.errors import InputError
from graphtrack.geometry.camera import Calibration, Camera, load_calibration, save_calibration
from graphtrack.io.bag_write import write_bag
from graphtrack.io.folder import write_folder
from graphtrack.io.handeye import save_handeye
from graphtrack.io.labels import write_labels
from graphtrack.io.recording import open_recording

H, W = 48, 64
NO_ROBOT = {"robot_loader": lambda p: None}
K = np.array([[50.0, 0, 31.5], [0, 52.0, 23.5], [0, 0, 1]])


def rot(rvec):
    return cv2.Rodrigues(np.asarray(rvec, float))[0]


def stereo_calibration(rectified: bool) -> Calibration:
    left = Camera(K.copy(), np.zeros(5) if rectified else np.array([-0.2, 0.05, 1e-3, -1e-3, 0.0]), H, W)
    if rectified:
        return Calibration(left, Camera(K.copy(), np.zeros(5), H, W), np.eye(3), np.array([-0.005, 0.0, 0.0]))
    K2 = K.copy()
    K2[0, 2] += 1.5
    right = Camera(K2, np.array([-0.18, 0.04, 0.0, 5e-4, 0.0]), H, W)
    return Calibration(left, right, rot([0.01, -0.035, 0.004]), np.array([-0.0049, 0.0002, 0.0003]))


def make_seq(seq: Path, calib: Calibration, n=6, right=True, drop=()):
    seq.mkdir(parents=True, exist_ok=True)
    robot = {"DH_params": [{"type": "revolute", "alpha": 0, "A": 0, "theta": 0, "D": 0}] * 6, "has_gripper": True}
    (seq / "robot.json").write_text(json.dumps(robot))
    save_calibration(seq / "camera_calibration.yaml", calib)
    E = np.eye(4)
    E[2, 3] = 0.1                       # the arm's base 100 mm in front of the camera
    save_handeye(seq / "handeye.yaml", E)
    rng = np.random.default_rng(3)
    frames = [NS(stamp=1_600_000_000.0 + i / 30, image=rng.integers(0, 256, (H, W, 3), dtype=np.uint8),
                 joints=rng.normal(size=6), jaw=0.1,
                 image_right=None if (not right or i in drop) else rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
              for i in range(n)]
    return frames


@pytest.mark.parametrize("form", ["folder", "bag", "bag-compressed"])
@pytest.mark.parametrize("rectified", [True, False])
def test_round_trip(tmp_path, form, rectified):
    calib = stereo_calibration(rectified)
    seq = tmp_path / "seq"
    frames = make_seq(seq, calib)
    if form == "folder":
        write_folder(seq, frames)
    else:
        write_bag(seq / "r.bag", frames, compressed=form == "bag-compressed")
    write_labels(seq / "labels_right.csv", {1: np.array([3.5, 4.25])})
    rec = open_recording(seq, **NO_ROBOT)
    assert rec.stereo and rec.labels_right[1].tolist() == [3.5, 4.25]
    out = list(rec.frames())
    assert len(out) == len(frames)
    for f, ref in zip(out, frames):
        np.testing.assert_array_equal(f.image, ref.image)
        np.testing.assert_array_equal(f.image_right, ref.image_right)
    assert sum(rec.right_skips.values()) == 0 and rec.warnings == []
    c = rec.calibration
    np.testing.assert_allclose(c.R, calib.R, atol=1e-12)
    np.testing.assert_allclose(c.T, calib.T, atol=1e-12)          # file mm -> metres
    assert (seq / "camera_calibration.yaml").read_text().count("T: [") == 1
    assert load_calibration(seq / "camera_calibration.yaml").T[0] == pytest.approx(calib.T[0])


def test_mono_recording_has_no_right_images(tmp_path):
    seq = tmp_path / "seq"
    frames = make_seq(seq, Calibration(Camera(K.copy(), np.zeros(5), H, W)), right=False)
    write_bag(seq / "r.bag", frames)
    rec = open_recording(seq, **NO_ROBOT)
    assert not rec.stereo and rec.labels_right is None
    assert all(f.image_right is None for f in rec.frames()) and sum(rec.right_skips.values()) == 0


@pytest.mark.parametrize("form", ["folder", "bag"])
def test_a_mono_read_leaves_the_right_images_unread(tmp_path, form):
    """frames(right=False) (a --mono run): the left images as recorded, no right image,
    nothing counted as skipped; a missing right frame is not looked for."""
    seq = tmp_path / "seq"
    frames = make_seq(seq, stereo_calibration(True), drop=(2,))
    (write_folder(seq, frames) if form == "folder" else write_bag(seq / "r.bag", frames))
    rec = open_recording(seq, **NO_ROBOT)
    out = list(rec.frames(right=False))
    assert len(out) == len(frames) and all(f.image_right is None for f in out)
    for f, ref in zip(out, frames):
        np.testing.assert_array_equal(f.image, ref.image)
    assert sum(rec.right_skips.values()) == 0 and rec.stereo


@pytest.mark.parametrize("form", ["folder", "bag"])
def test_missing_right_frame_is_left_only_and_counted(tmp_path, form):
    seq = tmp_path / "seq"
    frames = make_seq(seq, stereo_calibration(True), drop=(2,))
    (write_folder(seq, frames) if form == "folder" else write_bag(seq / "r.bag", frames))
    rec = open_recording(seq, **NO_ROBOT)
    out = list(rec.frames())
    assert [f.image_right is None for f in out] == [False, False, True, False, False, False]
    np.testing.assert_array_equal(out[3].image_right, frames[3].image_right)   # no shift after the gap
    assert rec.right_skips["missing"] == 1
    assert any("1 frames without a usable right image" in w for w in rec.warnings)


def test_corrupt_right_file_and_wrong_size(tmp_path):
    seq = tmp_path / "seq"
    frames = make_seq(seq, stereo_calibration(False))
    frames[4].image_right = np.zeros((H + 2, W, 3), np.uint8)
    write_folder(seq, frames)
    (seq / "frames_right" / "000001.png").write_bytes(b"not a png")
    rec = open_recording(seq, **NO_ROBOT)
    out = list(rec.frames())
    assert [f.image_right is None for f in out] == [False, True, False, False, True, False]
    assert rec.right_skips == {"missing": 0, "corrupt": 1, "image_size": 1, "same_as_left": 0}


def test_a_right_image_copied_from_the_left_is_left_only(tmp_path):
    """frames_right/ a copy of frames/ (tracked 0.35 -> 17.5 mm with exit 0): each identical
    pair is a counted same_as_left skip, and the warning says what it means."""
    seq = tmp_path / "seq"
    frames = make_seq(seq, stereo_calibration(False))
    for k in (0, 2, 3):
        frames[k].image_right = frames[k].image.copy()
    frames[5].image = np.zeros_like(frames[5].image)           # the light off: both black, not a copy
    frames[5].image_right = frames[5].image.copy()
    write_folder(seq, frames)
    rec = open_recording(seq, **NO_ROBOT)
    out = list(rec.frames())
    assert [f.image_right is None for f in out] == [True, False, True, True, False, False]
    assert rec.right_skips["same_as_left"] == 3
    assert "same_as_left 3); left-only for those: a right image identical to its left one is a copy" in \
        rec.right_skip_warning


def test_right_images_numbered_from_1_are_unused_and_extras_noted(tmp_path):
    """frames_right/ numbered from 1 (each right image would pair with the wrong frame): left-only
    with a warning; right images beyond the rows (a right camera that saved one more) are
    noted and unused, the pairs by name kept."""
    seq = tmp_path / "seq"
    write_folder(seq, make_seq(seq, stereo_calibration(False)))
    right = seq / "frames_right"
    for q in sorted(right.iterdir(), reverse=True):
        q.rename(q.with_name(f"{int(q.stem) + 1:06d}{q.suffix}"))
    rec = open_recording(seq, **NO_ROBOT)
    assert not rec.stereo and all(f.image_right is None for f in rec.frames())
    assert [w for w in rec.warnings if "frames_right" in w] == [
        f"{right}: the right images are numbered 1..6 for frames 0..5: each would pair with the wrong frame, "
        "so they are not used (left-only); rename them from 000000"]
    (right / "000006.png").rename(right / "000000.png")
    (right / "000009.png").write_bytes((right / "000001.png").read_bytes())
    rec = open_recording(seq, **NO_ROBOT)
    assert rec.stereo and all(f.image_right is not None for f in rec.frames())
    assert f"{right}: 1 right images beyond joints.csv's 6 rows (first: 000009.png) are not used" in rec.warnings


def test_bag_right_matched_by_stamp_not_order(tmp_path):
    """Right stamps offset by +4 ms (within tolerance) and one right image missing in the middle."""
    from graphtrack.io import bag

    seq = tmp_path / "seq"
    frames = make_seq(seq, stereo_calibration(True), n=5)
    lefts = [NS(stamp=f.stamp, image=f.image, joints=f.joints, jaw=f.jaw) for f in frames]
    rights = [NS(stamp=f.stamp + 0.004, image=f.image_right, joints=f.joints, jaw=f.jaw)
              for i, f in enumerate(frames) if i != 1]
    write_bag(tmp_path / "l.bag", lefts)
    write_bag(tmp_path / "r.bag", rights)
    _merge_bags(tmp_path / "l.bag", tmp_path / "r.bag", seq / "s.bag", bag.IMAGE_TOPIC, bag.RIGHT_IMAGE_TOPIC)
    rec = open_recording(seq, **NO_ROBOT)
    out = list(rec.frames())
    assert [f.image_right is None for f in out] == [False, True, False, False, False]
    for f in out:
        if f.image_right is not None:
            np.testing.assert_array_equal(f.image_right, frames[f.index].image_right)
    assert rec.right_skips["missing"] == 1


@pytest.mark.parametrize("offset_ms, shift", [(12.0, 0), (-16.0, 0), (17.5, 1)])
def test_bag_right_paired_within_half_a_period(tmp_path, offset_ms, shift):
    """Two free-running cameras at 30 frames/s are up to 16.7 ms apart: a left image takes the
    right image nearest in time within half the streams' period (17.5 ms after left k is
    15.8 ms before left k + 1: that frame's pair). The first frame, before the left period
    is known, pairs within 10 ms only."""
    from graphtrack.io import bag

    seq = tmp_path / "seq"
    frames = make_seq(seq, stereo_calibration(True), n=5)
    lefts = [NS(stamp=f.stamp, image=f.image, joints=f.joints, jaw=f.jaw) for f in frames]
    rights = [NS(stamp=f.stamp + offset_ms / 1e3, image=f.image_right, joints=f.joints, jaw=f.jaw)
              for f in frames]
    write_bag(tmp_path / "l.bag", lefts)
    write_bag(tmp_path / "r.bag", rights)
    _merge_bags(tmp_path / "l.bag", tmp_path / "r.bag", seq / "s.bag", bag.IMAGE_TOPIC, bag.RIGHT_IMAGE_TOPIC)
    rec = open_recording(seq, **NO_ROBOT)
    out = list(rec.frames())
    assert rec.right_skips["missing"] == 1 and out[0].image_right is None
    for f in out[1:]:
        np.testing.assert_array_equal(f.image_right, frames[f.index - shift].image_right)


def test_bag_right_stream_slower_than_the_left(tmp_path):
    """Right images at half the left rate, 30 ms after every other left image: each pairs
    with the left image 3.3 ms from it, not the one 30 ms before it (half the LEFT period)."""
    from graphtrack.io import bag

    seq = tmp_path / "seq"
    frames = make_seq(seq, stereo_calibration(True), n=6)
    lefts = [NS(stamp=f.stamp, image=f.image, joints=f.joints, jaw=f.jaw) for f in frames]
    rights = [NS(stamp=f.stamp + 0.030, image=f.image_right, joints=f.joints, jaw=f.jaw) for f in frames[::2]]
    write_bag(tmp_path / "l.bag", lefts)
    write_bag(tmp_path / "r.bag", rights)
    _merge_bags(tmp_path / "l.bag", tmp_path / "r.bag", seq / "s.bag", bag.IMAGE_TOPIC, bag.RIGHT_IMAGE_TOPIC)
    out = list(open_recording(seq, **NO_ROBOT).frames())
    assert [f.image_right is not None for f in out] == [False, True, False, True, False, True]
    for f in out[1::2]:
        np.testing.assert_array_equal(f.image_right, frames[f.index - 1].image_right)


def _merge_bags(left, right, out, left_topic, right_topic, left_as=None):
    """Left bag as is (its image topic renamed to ``left_as`` if given) + the right bag's
    image messages renamed to the right topic."""
    from rosbags.rosbag1 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    msgs = []
    with Reader(left) as r:
        for c, t, raw in r.messages():
            msgs.append((t, left_as if left_as and c.topic == left_topic else c.topic, c.msgtype, raw))
    with Reader(right) as r:
        for c, t, raw in r.messages():
            if c.topic == left_topic:
                msgs.append((t, right_topic, c.msgtype, raw))
    with Writer(out) as w:
        conns = {}
        for t, topic, typ, raw in sorted(msgs, key=lambda m: m[0]):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typ, typestore=ts)
            w.write(conns[topic], t, raw)


def test_bag_right_topic_of_another_name(tmp_path):
    """A camera driver's names: --image-topic /endo/left/image_raw finds its twin
    /endo/right/image_raw (and says so); --right-image-topic names it too; naming the
    left image's topic as the right one, or a topic without messages, is refused."""
    from graphtrack.io.topics import TopicSelection

    seq = tmp_path / "seq"
    frames = make_seq(seq, stereo_calibration(True), n=4)
    lefts = [NS(stamp=f.stamp, image=f.image, joints=f.joints, jaw=f.jaw) for f in frames]
    rights = [NS(stamp=f.stamp, image=f.image_right, joints=f.joints, jaw=f.jaw) for f in frames]
    write_bag(tmp_path / "l.bag", lefts)
    write_bag(tmp_path / "r.bag", rights)
    from graphtrack.io import bag

    _merge_bags(tmp_path / "l.bag", tmp_path / "r.bag", seq / "s.bag", bag.IMAGE_TOPIC, "/endo/right/image_raw",
                left_as="/endo/left/image_raw")
    for sel, note in ((TopicSelection(image="/endo/left/image_raw"), True),
                      (TopicSelection(image="/endo/left/image_raw", right="/endo/right/image_raw"), False)):
        rec = open_recording(seq, **NO_ROBOT, topics=sel)
        out = list(rec.frames())
        assert rec.stereo and all(f.image_right is not None for f in out)
        assert any("twin of --image-topic" in w for w in rec.warnings) == note
        np.testing.assert_array_equal(out[2].image_right, frames[2].image_right)
    for right, why in (("/nope", "no messages on --right-image-topic /nope"),
                       ("/endo/left/image_raw", "--right-image-topic /endo/left/image_raw is the left image's topic")):
        with pytest.raises(InputError, match=why):
            open_recording(seq, **NO_ROBOT, topics=TopicSelection(image="/endo/left/image_raw", right=right))


@pytest.mark.parametrize("rectified", [True, False])
def test_right_projection_matches_opencv(tmp_path, rectified):
    calib = stereo_calibration(rectified)
    save_calibration(tmp_path / "c.yaml", calib)
    c = load_calibration(tmp_path / "c.yaml")
    P = np.array([[0.01, -0.005, 0.08], [-0.02, 0.01, 0.12], [0.0, 0.0, 0.1]])
    rvec = cv2.Rodrigues(calib.R)[0]
    ref, _ = cv2.projectPoints(P, rvec, calib.T, calib.right.K, calib.right.dist)
    np.testing.assert_allclose(c.project_right(P), ref.reshape(-1, 2), atol=1e-9)
    np.testing.assert_allclose(c.right_T_left[:3, 3], calib.T, atol=1e-12)
    if rectified:  # same row, disparity f b / Z
        uvl = c.left.project_raw(P)
        np.testing.assert_allclose(c.project_right(P)[:, 1], uvl[:, 1], atol=1e-9)
        np.testing.assert_allclose(uvl[:, 0] - c.project_right(P)[:, 0], K[0, 0] * 0.005 / P[:, 2], atol=1e-9)
    img = np.random.default_rng(0).integers(0, 256, (H, W, 3), dtype=np.uint8)
    np.testing.assert_array_equal(c.undistort_right(img), cv2.remap(img, *cv2.initUndistortRectifyMap(
        c.right.K, c.right.dist, None, c.right.K, (W, H), cv2.CV_16SC2), cv2.INTER_LINEAR))


def test_R_must_be_a_rotation(tmp_path):
    calib = stereo_calibration(True)
    calib.R = np.diag([1.0, 1.0, 2.0])
    save_calibration(tmp_path / "c.yaml", calib)
    with pytest.raises(InputError, match="'R' is not a rotation"):
        load_calibration(tmp_path / "c.yaml")
