"""Recordings in: ROS 1/2 bags and the plain-folder form, round trips, sync, bad input."""
import json
import shutil
import tracemalloc
from pathlib import Path
from types import SimpleNamespace as NS

import cv2
import numpy as np
import pytest

from graphtrack.errors import FrameError, InputError
from graphtrack.geometry.camera import Calibration, Camera, save_calibration
from graphtrack.io.bag import COMPRESSED_TOPIC, IMAGE_TOPIC
from graphtrack.io.image_msg import decode_image
from graphtrack.io.bag_write import write_bag
from graphtrack.io.folder import write_folder
from graphtrack.io.handeye import save_handeye
from graphtrack.io.recording import open_recording
from graphtrack.robot.kinematics import check_joints

H, W = 48, 64
JOINTS, JAW = "/dvrk/PSM1/state_joint_current", "/dvrk/PSM1/state_jaw_current"
NO_ROBOT = {"robot_loader": lambda p: None}


# -- helpers --------------------------------------------------------------------------------
def make_frames(n=8, h=H, w=W, jaw=True, seed=0, t0=1_600_000_000.0):
    rng = np.random.default_rng(seed)
    return [NS(stamp=t0 + i * 0.05, image=rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
               joints=0.2 * rng.normal(size=6), jaw=0.01 * i if jaw else float("nan")) for i in range(n)]


def write_meta(seq: Path, h=H, w=W, n_dh=6, labels=None):
    seq.mkdir(parents=True, exist_ok=True)
    robot = {"DH_params": [{"type": "revolute", "alpha": 0, "A": 0, "theta": 0, "D": 0}] * n_dh,
             "has_gripper": True}
    (seq / "robot.json").write_text(json.dumps(robot))
    K = np.array([[50.0, 0, w / 2], [0, 50.0, h / 2], [0, 0, 1]])
    save_calibration(seq / "camera_calibration.yaml", Calibration(Camera(K, np.zeros(5), h, w)))
    T = np.eye(4)
    T[:3, 3] = [0.01, 0.02, 0.1]
    save_handeye(seq / "handeye.yaml", T)
    if labels is not None:
        (seq / "labels.csv").write_text(labels)
    return seq


def bag_seq(tmp_path, frames=None, name="rec.bag", **kw):
    seq = write_meta(tmp_path / "seq")
    write_bag(seq / name, frames if frames is not None else make_frames(), **kw)
    return seq


def typestore(ros2=False):
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)


def msg_header(ts, t_ns, ros2=False):
    T = ts.types
    stamp = T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id="") if ros2 else \
        T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="")


def image_msg(ts, t_ns, img, encoding="bgr8", ros2=False):
    c = 1 if img.ndim == 2 else img.shape[2]
    return ts.types["sensor_msgs/msg/Image"](
        header=msg_header(ts, t_ns, ros2), height=img.shape[0], width=img.shape[1], encoding=encoding,
        is_bigendian=0, step=img.shape[1] * c, data=np.ascontiguousarray(img).ravel())


def joint_msg(ts, t_ns, pos, ros2=False):
    e = np.zeros(0)
    return ts.types["sensor_msgs/msg/JointState"](header=msg_header(ts, t_ns, ros2), name=[],
                                                  position=np.asarray(pos, float), velocity=e, effort=e)


def write_custom_bag(path, messages, ros2=False, storage="sqlite3"):
    """messages: (topic, msgtype, record time ns, message) in write order."""
    ts = typestore(ros2)
    if ros2:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(path, version=9, storage_plugin=StoragePlugin[storage.upper()])
    else:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    conns = {}
    with writer:
        for topic, msgtype, t, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            data = ts.serialize_cdr(msg, msgtype) if ros2 else ts.serialize_ros1(msg, msgtype)
            writer.write(conns[topic], t, data)


def items(rec, **kw):
    return list(rec.frames(**kw))


def ok_frames(out):
    assert all(not isinstance(f, FrameError) for f in out), [str(f) for f in out if isinstance(f, FrameError)]
    return out


# -- bag round trips ------------------------------------------------------------------------
@pytest.mark.parametrize("compressed,fmt", [(False, "png"), (True, "png")])
def test_bag_roundtrip_lossless(tmp_path, compressed, fmt):
    frames = make_frames()
    seq = bag_seq(tmp_path, frames, compressed=compressed, image_format=fmt)
    rec = open_recording(seq, **NO_ROBOT)
    assert rec.kind == "bag" and len(rec) == len(frames) and rec.image_size == (H, W)
    assert rec.source.image_topic == (COMPRESSED_TOPIC if compressed else IMAGE_TOPIC)
    assert rec.has_jaw and not rec.truncated and rec.n_joints == 6 and rec.labels is None
    np.testing.assert_allclose(rec.handeye[:3, 3], [0.01, 0.02, 0.1])
    out = ok_frames(items(rec))
    assert [f.index for f in out] == list(range(len(frames)))
    for f, ref in zip(out, frames):
        assert f.image.dtype == np.uint8 and f.image.shape == (H, W, 3)
        np.testing.assert_array_equal(f.image, ref.image)
        np.testing.assert_array_equal(f.joints, ref.joints)
        assert f.jaw == ref.jaw and abs(f.stamp - ref.stamp) < 1e-6
    np.testing.assert_allclose(rec.stamps, [f.stamp for f in frames], atol=1e-6, rtol=0)


def test_bag_roundtrip_jpeg(tmp_path):
    frames = make_frames()
    for f in frames:  # smooth images so jpeg is close
        f.image = cv2.GaussianBlur(f.image, (0, 0), 4)
    rec = open_recording(bag_seq(tmp_path, frames, compressed=True, image_format="jpeg"), **NO_ROBOT)
    for f, ref in zip(ok_frames(items(rec)), frames):
        assert np.abs(f.image.astype(int) - ref.image).mean() < 3
        np.testing.assert_array_equal(f.joints, ref.joints)


def test_bag_without_jaw_topic_gives_nan_jaw(tmp_path):
    rec = open_recording(bag_seq(tmp_path, make_frames(jaw=False)), **NO_ROBOT)
    assert not rec.has_jaw
    assert all(np.isnan(f.jaw) for f in ok_frames(items(rec)))


def test_frames_start(tmp_path):
    frames = make_frames()
    rec = open_recording(bag_seq(tmp_path, frames), **NO_ROBOT)
    out = ok_frames(items(rec, start=5))
    assert [f.index for f in out] == [5, 6, 7]
    np.testing.assert_array_equal(out[0].image, frames[5].image)


def test_labels_and_real_robot_loader(tmp_path):
    from graphtrack.robot import description as desc
    from graphtrack.robot import psm
    seq = bag_seq(tmp_path)
    (seq / "labels.csv").write_text("frame,u,v\n0,10.5,20.25\n3,1,2\n")
    desc.save_robot_json(seq / "robot.json", psm.psm_large_needle_driver())
    rec = open_recording(seq)
    assert rec.robot.n_dh == 6 and rec.n_joints == 6
    assert sorted(rec.labels) == [0, 3] and rec.labels[0].tolist() == [10.5, 20.25]
    assert len(ok_frames(items(rec))) == 8


@pytest.mark.parametrize("first, from_one", [(1, True), (0, False)])
def test_labels_numbered_from_one_are_named(tmp_path, first, from_one):
    """labels.csv rows 1..n for a recording of frames 0..n-1: the one beyond the end is not
    scored and the note asks whether they are numbered from 1 (each other label would be
    scored against the next frame); rows 0..n: only the count."""
    seq = write_meta(tmp_path / "seq")
    write_folder(seq, make_frames(3))
    (seq / "labels.csv").write_text("frame,u,v\n" + "".join(f"{k},10,20\n" for k in range(first, 4)))
    got = [w for w in open_recording(seq, **NO_ROBOT).warnings if "labels.csv" in w]
    assert len(got) == 1 and "1 labels of frames the recording does not have (it has 3 frames; first: frame 3)" in got[0]
    assert ("numbered from 1?" in got[0]) is from_one


def test_decode_image_encodings():
    ts = typestore()
    rng = np.random.default_rng(5)
    bgr = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    msg = image_msg(ts, 1, bgr, "bgr8")
    np.testing.assert_array_equal(decode_image(msg, "sensor_msgs/msg/Image", "x"), bgr)
    msg = image_msg(ts, 1, bgr[..., ::-1], "rgb8")
    np.testing.assert_array_equal(decode_image(msg, "sensor_msgs/msg/Image", "x"), bgr)
    gray = bgr[..., 0]
    out = decode_image(image_msg(ts, 1, gray, "mono8"), "sensor_msgs/msg/Image", "x")
    np.testing.assert_array_equal(out, np.repeat(gray[..., None], 3, 2))
    padded = np.zeros((5, 8, 3), np.uint8)  # step has one pixel of row padding
    padded[:, :7] = bgr
    msg = image_msg(ts, 1, padded, "bgr8")
    msg.width = 7
    np.testing.assert_array_equal(decode_image(msg, "sensor_msgs/msg/Image", "x"), bgr)


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
def test_decode_bayer_mosaics(pattern):
    """A flat colour mosaicked by hand in the ROS pattern (its top-left 2x2, row by row)
    demosaics back to that colour away from the border (oracle: the colour itself)."""
    colour = {"b": 200, "g": 100, "r": 30}
    mosaic = np.zeros((12, 16), np.uint8)
    for k, ch in enumerate(pattern):
        mosaic[k // 2::2, k % 2::2] = colour[ch]
    out = decode_image(image_msg(typestore(), 1, mosaic, f"bayer_{pattern}8"), "sensor_msgs/msg/Image", "x")
    assert out.shape == (12, 16, 3)
    np.testing.assert_array_equal(out[2:-2, 2:-2].reshape(-1, 3), np.tile([200, 100, 30], (8 * 12, 1)))


# -- synchronisation ------------------------------------------------------------------------
def test_nearest_header_stamp_sync(tmp_path):
    """Joints at 7 Hz with offset stamps, written out of stamp order and with record times
    unrelated to the header stamps: each frame takes the reading with the nearest HEADER stamp."""
    ts = typestore()
    s = 10**9
    img = np.zeros((H, W, 3), np.uint8)
    img_t = [int(2 * s + k * s / 10) for k in range(10)]           # images at 2.0, 2.1, ...
    joint_t = [int(1.95 * s + k * s / 7) for k in range(9)]        # joints at 1.95 + k/7
    jaw_t = [int(2.02 * s + k * s / 4) for k in range(4)]          # jaw at 2.02 + k/4
    msgs = [(IMAGE_TOPIC, "sensor_msgs/msg/Image", 5 * s + k, image_msg(ts, t, img)) for k, t in enumerate(img_t)]
    order = [3, 0, 8, 1, 5, 2, 7, 4, 6]
    msgs += [(JOINTS, "sensor_msgs/msg/JointState", 5 * s + k, joint_msg(ts, joint_t[k], [k] * 6)) for k in order]
    msgs += [(JAW, "sensor_msgs/msg/JointState", 6 * s, joint_msg(ts, t, [10.0 + k])) for k, t in enumerate(jaw_t)]
    seq = write_meta(tmp_path / "seq")
    write_custom_bag(seq / "rec.bag", msgs)
    out = ok_frames(items(open_recording(seq, **NO_ROBOT)))
    for f, t in zip(out, img_t):
        assert f.stamp == pytest.approx(t / 1e9, abs=1e-9)
        k = int(np.argmin([abs(t - jt) for jt in joint_t]))
        assert f.joints.tolist() == [float(k)] * 6, (f.index, k)
        assert f.jaw == 10.0 + int(np.argmin([abs(t - jt) for jt in jaw_t]))


def test_sync_tie_takes_earlier_and_zero_stamp_uses_record_time(tmp_path):
    ts = typestore()
    s = 10**7   # 10 ms: every image has a joint reading within MAX_JOINT_GAP_S
    img = np.zeros((H, W, 3), np.uint8)
    msgs = [(JOINTS, "sensor_msgs/msg/JointState", 1, joint_msg(ts, 9 * s, [9.0] * 6)),
            (JOINTS, "sensor_msgs/msg/JointState", 2, joint_msg(ts, 11 * s, [11.0] * 6)),
            (JOINTS, "sensor_msgs/msg/JointState", 3, joint_msg(ts, 20 * s, [20.0] * 6)),
            (IMAGE_TOPIC, "sensor_msgs/msg/Image", 4, image_msg(ts, 10 * s, img)),   # tie 9 / 11
            (IMAGE_TOPIC, "sensor_msgs/msg/Image", 19 * s, image_msg(ts, 0, img))]   # stamp unset
    seq = write_meta(tmp_path / "seq")
    write_custom_bag(seq / "rec.bag", msgs)
    out = ok_frames(items(open_recording(seq, **NO_ROBOT)))
    assert out[0].joints[0] == 9.0
    assert out[1].stamp == 19 * s / 1e9 and out[1].joints[0] == 20.0


# -- ROS 2 ----------------------------------------------------------------------------------
@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_ros2_bag(tmp_path, storage):
    frames = make_frames(5)
    seq = write_meta(tmp_path / "seq")
    write_custom_bag(seq / "rec2", _ros2_messages(frames), ros2=True, storage=storage)
    rec = open_recording(seq, **NO_ROBOT)
    assert rec.kind == "ros2" and len(rec) == 5
    for f, ref in zip(ok_frames(items(rec)), frames):
        np.testing.assert_array_equal(f.image, ref.image)
        np.testing.assert_array_equal(f.joints, ref.joints)
        assert f.jaw == ref.jaw
    np.testing.assert_allclose(rec.stamps, [f.stamp for f in frames], atol=1e-6, rtol=0)


def _ros2_messages(frames, image_topic=IMAGE_TOPIC):
    ts = typestore(ros2=True)
    msgs = []
    for f in frames:
        t = int(round(f.stamp * 1e9))
        if image_topic == COMPRESSED_TOPIC:
            data = np.frombuffer(cv2.imencode(".png", f.image)[1].tobytes(), np.uint8)
            img = ts.types["sensor_msgs/msg/CompressedImage"](header=msg_header(ts, t, True), format="png",
                                                              data=data)
            msgs.append((image_topic, "sensor_msgs/msg/CompressedImage", t, img))
        else:
            msgs.append((image_topic, "sensor_msgs/msg/Image", t, image_msg(ts, t, f.image, "bgr8", True)))
        msgs += [(JOINTS, "sensor_msgs/msg/JointState", t, joint_msg(ts, t, f.joints, True)),
                 (JAW, "sensor_msgs/msg/JointState", t, joint_msg(ts, t, [f.jaw], True))]
    return msgs


def test_the_sequence_folder_may_be_the_ros2_bag(tmp_path):
    """`ros2 bag record -o SEQ`, then robot.json, camera_calibration.yaml and handeye.yaml added to SEQ."""
    frames = make_frames(3)
    write_custom_bag(tmp_path / "seq", _ros2_messages(frames), ros2=True)
    seq = write_meta(tmp_path / "seq")
    rec = open_recording(seq, **NO_ROBOT)
    assert rec.kind == "ros2" and len(rec) == 3
    assert [f.joints.tolist() for f in ok_frames(items(rec))] == [f.joints.tolist() for f in frames]


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_ros2_storage_without_metadata_names_reindex(tmp_path, storage):
    """A killed `ros2 bag record` leaves its storage file without metadata.yaml."""
    seq = write_meta(tmp_path / "seq")
    write_custom_bag(seq / "rosbag2", _ros2_messages(make_frames(2)), ros2=True, storage=storage)
    (seq / "rosbag2" / "metadata.yaml").unlink()
    with pytest.raises(InputError, match=r"rosbag2: ROS 2 bag storage \(rosbag2.*\) without metadata.yaml") as e:
        open_recording(seq, **NO_ROBOT)
    assert f"ros2 bag reindex {seq / 'rosbag2'}" in str(e.value)


def test_an_empty_raw_image_topic_falls_back_to_the_compressed_one(tmp_path):
    """The raw topic advertised (a connection without messages), the images on .../compressed."""
    from rosbags.rosbag2 import Writer

    frames = make_frames(3)
    seq = write_meta(tmp_path / "seq")
    ts = typestore(ros2=True)
    with Writer(seq / "rec2", version=9) as w:
        w.add_connection(IMAGE_TOPIC, "sensor_msgs/msg/Image", typestore=ts)
        conns = {}
        for topic, msgtype, t, msg in _ros2_messages(frames, COMPRESSED_TOPIC):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=ts)
            w.write(conns[topic], t, ts.serialize_cdr(msg, msgtype))
    rec = open_recording(seq, **NO_ROBOT)
    assert rec.source.image_topic == COMPRESSED_TOPIC and len(rec) == 3
    for f, ref in zip(ok_frames(items(rec)), frames):
        np.testing.assert_array_equal(f.image, ref.image)


# -- streaming --------------------------------------------------------------------------------
def test_bag_reading_streams(tmp_path):
    """60 frames of 240x320 (13.8 MB of images): reading them one by one stays far below that."""
    rng = np.random.default_rng(9)
    base = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    frames = (NS(stamp=1.0 + i, image=np.roll(base, i, 0), joints=np.zeros(6), jaw=0.0) for i in range(60))
    seq = write_meta(tmp_path / "seq", h=240, w=320)
    write_bag(seq / "rec.bag", frames)
    rec = open_recording(seq, **NO_ROBOT)
    tracemalloc.start()
    n = 0
    for f in rec.frames():
        assert not isinstance(f, FrameError)
        n += 1
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert n == 60 and peak < 6e6, peak


# -- truncated / damaged bags ---------------------------------------------------------------
@pytest.mark.parametrize("frac", [0.2, 0.45, 0.7, 0.9, 0.999])
def test_truncated_bag_yields_complete_prefix(tmp_path, frac):
    frames = make_frames(30, h=96, w=128, seed=3)
    src = tmp_path / "full.bag"
    write_bag(src, frames)
    seq = write_meta(tmp_path / "seq", h=96, w=128)
    data = src.read_bytes()
    (seq / "rec.bag").write_bytes(data[: int(len(data) * frac)])
    rec = open_recording(seq, **NO_ROBOT)
    assert rec.truncated and any("rec.bag" in w and "damage" in w for w in rec.warnings)
    out = ok_frames(items(rec))
    assert len(out) == len(rec) and 0 < len(out) <= 30
    assert len(out) == 30 or frac < 0.99  # cutting only the index loses no frame
    assert [f.index for f in out] == list(range(len(out)))
    for f in out:  # a complete, correctly synchronised prefix
        np.testing.assert_array_equal(f.image, frames[f.index].image)
        np.testing.assert_array_equal(f.joints, frames[f.index].joints)
        assert f.jaw == frames[f.index].jaw


@pytest.mark.parametrize("name", ["rec.bag", "rec.bag.active"])
def test_unindexed_bag_is_read_by_scanning(tmp_path, name):
    frames = make_frames(12)
    seq = write_meta(tmp_path / "seq")
    write_bag(seq / "tmp.bag", frames, chunk_compression="lz4")
    data = bytearray((seq / "tmp.bag").read_bytes())
    i = data.index(b"index_pos=") + len(b"index_pos=")
    data[i:i + 8] = bytes(8)  # what a killed `rosbag record` leaves: index_pos = 0
    (seq / "tmp.bag").unlink()
    (seq / name).write_bytes(bytes(data))
    rec = open_recording(seq, **NO_ROBOT)
    assert rec.truncated and len(rec) == 12
    out = ok_frames(items(rec, start=2))
    assert [f.index for f in out] == list(range(2, 12))
    np.testing.assert_array_equal(out[-1].image, frames[-1].image)


def test_bag_truncated_before_any_frame(tmp_path):
    src = tmp_path / "full.bag"
    write_bag(src, make_frames())
    seq = write_meta(tmp_path / "seq")
    (seq / "rec.bag").write_bytes(src.read_bytes()[:4200])
    with pytest.raises(InputError, match="rec.bag"):
        open_recording(seq, **NO_ROBOT)


def test_damaged_chunk_in_indexed_bag(tmp_path):
    """A chunk near the end that does not decompress: the frames before it are read, as from
    a truncated bag, with the last good frame named; one in the first chunk leaves none."""
    frames = make_frames(60, h=96, w=128)
    for where, left in ((0.85, True), (0.05, False)):
        seq = write_meta(tmp_path / f"seq{where}", h=96, w=128)
        write_bag(seq / "rec.bag", frames, chunk_compression="bz2")
        data = bytearray((seq / "rec.bag").read_bytes())
        at = int(len(data) * where)
        data[at:at + 64] = bytes(64)  # bz2 checks CRCs: this chunk no longer decompresses
        (seq / "rec.bag").write_bytes(bytes(data))
        rec = open_recording(seq, **NO_ROBOT)  # the index is intact: opening is fine
        if not left:
            with pytest.raises(InputError, match=r"rec\.bag: bag index unusable .*no complete left image"):
                items(rec)
            continue
        out = ok_frames(items(rec))            # the joint pass meets the damage: read up to it
        assert rec.truncated and 0 < len(out) < 60 and len(rec) == len(out)
        assert [f.index for f in out] == list(range(len(out)))
        for f in out:
            np.testing.assert_array_equal(f.image, frames[f.index].image)
        assert f"(the last good frame is {len(out) - 1})" in rec.warnings[-1]


@pytest.mark.parametrize("content", [b"", b"garbage, not a bag at all" * 10])
def test_not_a_bag(tmp_path, content):
    seq = write_meta(tmp_path / "seq")
    (seq / "rec.bag").write_bytes(content)
    with pytest.raises(InputError, match=r"rec\.bag: cannot read bag"):
        open_recording(seq, **NO_ROBOT)


# -- whole-recording errors -----------------------------------------------------------------
@pytest.mark.parametrize("missing", ["robot.json", "camera_calibration.yaml", "handeye.yaml"])
def test_missing_required_file(tmp_path, missing):
    seq = bag_seq(tmp_path)
    (seq / missing).unlink()
    with pytest.raises(InputError, match=missing.replace(".", r"\.") + ": file not found"):
        open_recording(seq, **NO_ROBOT)


def test_not_a_folder(tmp_path):
    with pytest.raises(InputError, match="not a folder"):
        open_recording(tmp_path / "nope", **NO_ROBOT)


def test_no_bag(tmp_path):
    seq = write_meta(tmp_path / "seq")
    with pytest.raises(InputError, match="no recording"):
        open_recording(seq, **NO_ROBOT)


def test_two_bags(tmp_path):
    seq = bag_seq(tmp_path)
    shutil.copy(seq / "rec.bag", seq / "other.bag")
    with pytest.raises(InputError) as e:
        open_recording(seq, **NO_ROBOT)
    assert "2 bags" in str(e.value) and "other.bag" in str(e.value) and "rec.bag" in str(e.value)


def test_two_bags_with_folder_form_uses_folder(tmp_path):
    seq = bag_seq(tmp_path)
    shutil.copy(seq / "rec.bag", seq / "other.bag")
    write_folder(seq, make_frames(3))
    rec = open_recording(seq, **NO_ROBOT)
    assert rec.kind == "folder" and len(rec) == 3 and any("2 bags" in w for w in rec.warnings)


def test_bag_without_image_topic(tmp_path):
    ts = typestore()
    seq = write_meta(tmp_path / "seq")
    write_custom_bag(seq / "rec.bag", [(JOINTS, "sensor_msgs/msg/JointState", 1, joint_msg(ts, 1, [0] * 6))])
    with pytest.raises(InputError) as e:
        open_recording(seq, **NO_ROBOT)
    assert "rec.bag" in str(e.value) and "/stereo/left/image" in str(e.value)


def test_bag_without_joint_topic(tmp_path):
    ts = typestore()
    seq = write_meta(tmp_path / "seq")
    img = np.zeros((H, W, 3), np.uint8)
    write_custom_bag(seq / "rec.bag", [(IMAGE_TOPIC, "sensor_msgs/msg/Image", 1, image_msg(ts, 1, img))])
    with pytest.raises(InputError) as e:
        open_recording(seq, **NO_ROBOT)
    assert "rec.bag" in str(e.value) and JOINTS in str(e.value)


def test_unsupported_encoding(tmp_path):
    ts = typestore()
    seq = write_meta(tmp_path / "seq")
    img = np.zeros((H, W, 3), np.uint8)
    write_custom_bag(seq / "rec.bag", [(IMAGE_TOPIC, "sensor_msgs/msg/Image", 1, image_msg(ts, 1, img, "yuv422")),
                                       (JOINTS, "sensor_msgs/msg/JointState", 1, joint_msg(ts, 1, [0] * 6))])
    with pytest.raises(InputError, match="yuv422"):
        items(open_recording(seq, **NO_ROBOT))


# -- per-frame errors -----------------------------------------------------------------------
def test_corrupt_images_in_bag(tmp_path):
    ts = typestore()
    T = ts.types
    seq = write_meta(tmp_path / "seq")
    good = cv2.imencode(".png", np.full((H, W, 3), 7, np.uint8))[1].ravel()
    bad = np.frombuffer(b"\x89PNG\r\n\x1a\n definitely not a png", np.uint8)
    msgs = []
    for k in range(4):
        t = (k + 1) * 10**8
        msgs.append((COMPRESSED_TOPIC, "sensor_msgs/msg/CompressedImage", t,
                     T["sensor_msgs/msg/CompressedImage"](header=msg_header(ts, t), format="png",
                                                          data=bad if k == 2 else good)))
        msgs.append((JOINTS, "sensor_msgs/msg/JointState", t, joint_msg(ts, t, [k] * 6)))
    write_custom_bag(seq / "rec.bag", msgs)
    out = items(open_recording(seq, **NO_ROBOT))
    assert [type(f).__name__ for f in out] == ["Frame", "Frame", "FrameError", "Frame"]
    assert out[2].reason == "corrupt_image" and out[2].frame == 2
    assert out[3].joints[0] == 3.0


def test_short_raw_image_is_corrupt(tmp_path):
    ts = typestore()
    seq = write_meta(tmp_path / "seq")
    msg = image_msg(ts, 5, np.zeros((H, W, 3), np.uint8))
    msg.data = msg.data[:100]
    write_custom_bag(seq / "rec.bag", [(IMAGE_TOPIC, "sensor_msgs/msg/Image", 5, msg),
                                       (JOINTS, "sensor_msgs/msg/JointState", 5, joint_msg(ts, 5, [0] * 6))])
    (err,) = items(open_recording(seq, **NO_ROBOT))
    assert isinstance(err, FrameError) and err.reason == "corrupt_image"


def test_image_size_mismatch(tmp_path):
    seq = write_meta(tmp_path / "seq", h=H + 2, w=W)
    write_bag(seq / "rec.bag", make_frames(3))
    out = items(open_recording(seq, **NO_ROBOT))
    assert [f.reason for f in out] == ["image_size"] * 3
    assert "64x48" in str(out[0]) and "64x50" in str(out[0])
    assert "times the size" not in str(out[0])     # another shape: no scale to suggest


def test_image_size_at_another_resolution_suggests_the_scale(tmp_path):
    seq = write_meta(tmp_path / "seq", h=2 * H, w=2 * W)   # calibrated at twice the recorded size
    write_bag(seq / "rec.bag", make_frames(2))
    out = items(open_recording(seq, **NO_ROBOT))
    assert [f.reason for f in out] == ["image_size"] * 2
    assert "calibrated at another resolution? scale ImageSize and K's fx, fy, cx, cy by 0.5" in str(out[0])


def test_nan_joints(tmp_path):
    frames = make_frames(4)
    frames[1].joints[3] = np.nan
    frames[2].joints[0] = np.inf
    out = items(open_recording(bag_seq(tmp_path, frames), **NO_ROBOT))
    assert [getattr(f, "reason", None) for f in out] == [None, "nan_joints", "nan_joints", None]


def test_joint_count(tmp_path):
    seq = bag_seq(tmp_path, make_frames(3))
    out = items(open_recording(seq, **NO_ROBOT), expected_joints=7)
    assert [f.reason for f in out] == ["joint_count"] * 3
    write_meta(seq, n_dh=7)  # robot.json now has 7 DH joints: the default expectation follows
    out = items(open_recording(seq, **NO_ROBOT))
    assert [f.reason for f in out] == ["joint_count"] * 3 and "7 DH joints" in str(out[0])
    assert len(ok_frames(items(open_recording(seq, expected_joints=6, **NO_ROBOT)))) == 3


# -- plain-folder form ----------------------------------------------------------------------
def test_folder_roundtrip(tmp_path):
    frames = make_frames(6)
    frames[4].jaw = float("nan")
    seq = write_meta(tmp_path / "seq")
    assert write_folder(seq, frames) == 6
    assert (seq / "joints.csv").read_text().splitlines()[0] == "frame,stamp,q1,q2,q3,q4,q5,q6,jaw"
    assert sorted(p.name for p in (seq / "frames").iterdir())[:2] == ["000000.png", "000001.png"]
    rec = open_recording(seq, **NO_ROBOT)
    assert rec.kind == "folder" and len(rec) == 6 and rec.has_jaw
    out = items(rec)
    assert out[4].reason == "nan_joints"  # this recording has jaw readings: a NaN one is bad
    for f in out[:4] + out[5:]:
        ref = frames[f.index]
        np.testing.assert_array_equal(f.image, ref.image)
        assert f.joints.tolist() == ref.joints.tolist() and f.jaw == ref.jaw and f.stamp == ref.stamp
    assert rec.stamps.tolist() == [f.stamp for f in frames]
    assert [getattr(f, "index", getattr(f, "frame", None)) for f in items(rec, start=3)] == [3, 4, 5]


def test_folder_video(tmp_path):
    frames = make_frames(10, jaw=False)
    for f in frames:
        f.image = cv2.GaussianBlur(f.image, (0, 0), 5)
    seq = write_meta(tmp_path / "seq")
    write_folder(seq, frames, video=True)
    assert (seq / "video.mp4").is_file() and not (seq / "frames").exists()
    rec = open_recording(seq, **NO_ROBOT)
    assert not rec.has_jaw and len(rec) == 10
    out = ok_frames(items(rec))
    for f in out:
        assert np.abs(f.image.astype(int) - frames[f.index].image).mean() < 12
        assert f.joints.tolist() == frames[f.index].joints.tolist() and np.isnan(f.jaw)
    later = ok_frames(items(rec, start=7))
    assert [f.index for f in later] == [7, 8, 9]
    np.testing.assert_array_equal(later[0].image, out[7].image)


def test_folder_video_shorter_than_joints(tmp_path):
    seq = write_meta(tmp_path / "seq")
    write_folder(seq, make_frames(4), video=True)
    with (seq / "joints.csv").open("a") as f:
        f.write("4,1700000000.0,0,0,0,0,0,0,0.1\n")
    out = items(open_recording(seq, **NO_ROBOT))
    assert len(out) == 5 and out[4].reason == "video_ended" and "video.mp4" in str(out[4])
    assert "ends after 4 frames and joints.csv has 5 rows: frame 4 has no image" in str(out[4])


def test_folder_video_that_stops_decoding_says_so(tmp_path):
    """A video whose container lists every row's frame but stops decoding at k is damaged,
    not short: the message says so (the later frames are not read)."""
    from graphtrack.io.folder import FolderSource

    seq = write_meta(tmp_path / "seq")
    write_folder(seq, make_frames(6), video=True)
    src = FolderSource(seq)
    assert src.video_frames == 6
    assert src._ended(2) == ("video.mp4 stopped decoding at frame 2 of the 6 its container lists (damaged?): "
                             "frames 2-5 have no image")


def test_a_joint_log_at_its_own_rate_is_told_to_be_resampled(tmp_path):
    """joints.csv at three rows per image (a joint logger's rate) pairs row k with image k:
    every frame gets another moment's joints, so the warning says what to do, not only
    that rows have no image."""
    seq = write_meta(tmp_path / "seq")
    frames = make_frames(4)
    write_folder(seq, frames)
    rows = ["frame,stamp,q1,q2,q3,q4,q5,q6,jaw"] + [f"{k},{1_600_000_000.0 + k / 90},0,0,0.1,0,0,0,0.1"
                                                    for k in range(12)]   # 90 rows/s for 4 images
    (seq / "joints.csv").write_text("\n".join(rows) + "\n")
    rec = open_recording(seq, **NO_ROBOT)
    assert any("12 rows for 4 images" in w and "resampled to the image stamps" in w for w in rec.warnings)
    assert not any("frames have no image" in w for w in rec.warnings)


def test_folder_corrupt_and_missing_images(tmp_path):
    seq = write_meta(tmp_path / "seq")
    write_folder(seq, make_frames(4))
    (seq / "frames" / "000001.png").write_bytes(b"not a png")
    (seq / "frames" / "000002.png").unlink()
    rec = open_recording(seq, **NO_ROBOT)
    out = items(rec)
    assert [getattr(f, "reason", None) for f in out] == [None, "corrupt_image", "missing_image", None]
    assert "missing" in str(out[2]) and any("1 of 4 frames have no image" in w for w in rec.warnings)


@pytest.mark.parametrize("header", ["frame,stamp,q1,q2,q3,q4,q5,q6",
                                    "frame,time,q1,q2,q3,q4,q5,q6,jaw",
                                    "frame,stamp,q1,q3,q2,q4,q5,q6,jaw",
                                    "frame,stamp,jaw"])
def test_folder_bad_joints_header(tmp_path, header):
    seq = write_meta(tmp_path / "seq")
    write_folder(seq, make_frames(2))
    lines = (seq / "joints.csv").read_text().splitlines()
    (seq / "joints.csv").write_text("\n".join([header] + lines[1:]) + "\n")
    with pytest.raises(InputError, match=r"joints\.csv: header must be 'frame,stamp,q1,...,qn,jaw'"):
        open_recording(seq, **NO_ROBOT)


def test_folder_joints_header_with_dvrk_names_in_any_order(tmp_path):
    """A joints.csv exported with the dVRK's joint names: the columns are put in DH order."""
    from graphtrack.io.joint_names import DVRK_PSM_JOINTS

    seq = write_meta(tmp_path / "seq")
    frames = make_frames(3)
    write_folder(seq, frames)
    rows = [r.split(",") for r in (seq / "joints.csv").read_text().splitlines()[1:]]
    perm = [3, 0, 5, 1, 4, 2]   # file column c holds DH joint perm[c]
    header = ["frame", "stamp", *(DVRK_PSM_JOINTS[j] for j in perm), "jaw"]
    body = [[r[0], r[1], *(r[2 + j] for j in perm), r[8]] for r in rows]
    (seq / "joints.csv").write_text("\n".join(",".join(r) for r in [header, *body]) + "\n")
    read = [f.joints.tolist() for f in ok_frames(items(open_recording(seq, **NO_ROBOT)))]
    assert read == [f.joints.tolist() for f in frames]


def test_folder_joints_header_with_some_dvrk_names_says_which(tmp_path):
    seq = write_meta(tmp_path / "seq")
    write_folder(seq, make_frames(2))
    lines = (seq / "joints.csv").read_text().splitlines()
    header = "frame,stamp,outer_yaw,outer_pitch,outer_insertion,outer_roll,outer_wrist_pitch,q6,jaw"
    (seq / "joints.csv").write_text("\n".join([header] + lines[1:]) + "\n")
    with pytest.raises(InputError, match=r"give each of the six once \(missing: outer_wrist_yaw\)"):
        open_recording(seq, **NO_ROBOT)
    six = "outer_yaw,outer_pitch,outer_insertion,outer_roll,outer_wrist_pitch,outer_wrist_yaw"
    (seq / "joints.csv").write_text("\n".join([f"frame,stamp,{six},extra,jaw"] + lines[1:]) + "\n")
    with pytest.raises(InputError, match=r"header must be") as err:   # every name once: no hint about them
        open_recording(seq, **NO_ROBOT)
    assert "give each" not in str(err.value)


@pytest.mark.parametrize("row,needle", [("5,1.0,0,0,0,0,0,0,0", "frame 5, expected 2"),
                                        ("2,1.0,0,0,0,0,0,0", "line 4 has 8 fields"),
                                        ("2,1.0,0,x,0,0,0,0,0", "line 4")])
def test_folder_bad_joints_rows(tmp_path, row, needle):
    seq = write_meta(tmp_path / "seq")
    write_folder(seq, make_frames(2))
    with (seq / "joints.csv").open("a") as f:
        f.write(row + "\n")
    with pytest.raises(InputError) as e:
        open_recording(seq, **NO_ROBOT)
    assert "joints.csv" in str(e.value) and needle in str(e.value)


def test_folder_without_joints_csv(tmp_path):
    seq = write_meta(tmp_path / "seq")
    write_folder(seq, make_frames(2))
    (seq / "joints.csv").unlink()
    with pytest.raises(InputError, match=r"joints\.csv: file not found"):
        open_recording(seq, **NO_ROBOT)


def test_a_principal_point_far_off_centre_is_warned_about(tmp_path):
    """K scaled for an image twice the size puts (cx, cy) near the corner: a warning naming
    camera_calibration.yaml; K at the centre, or a few per cent off it, says nothing."""
    from graphtrack.io.consistency import off_centre

    seq = write_meta(tmp_path / "seq")
    write_folder(seq, make_frames(2))
    assert not any("principal point" in w for w in open_recording(seq, **NO_ROBOT).warnings)
    for (cx, cy), far in (((W / 2, H / 2), False), ((0.55 * W, 0.45 * H), False), ((0.74 * W, H / 2), False),
                          ((W - 2, H - 2), True), ((W / 2, 0.2 * H), True)):
        cam = Camera(np.array([[50.0, 0, cx], [0, 50.0, cy], [0, 0, 1]]), np.zeros(5), H, W)
        assert off_centre(cam) == far
        save_calibration(seq / "camera_calibration.yaml", Calibration(cam))
        got = [w for w in open_recording(seq, **NO_ROBOT).warnings if "principal point" in w]
        assert len(got) == far and (not far or got[0].startswith(f"{seq / 'camera_calibration.yaml'}: K1's"))


def test_focal_lengths_far_apart_are_warned_about(tmp_path):
    """fy = 2 fx (a K of another height, or interlaced fields): a warning naming K1; 10 %
    apart says nothing."""
    seq = write_meta(tmp_path / "seq")
    write_folder(seq, make_frames(2))
    for fy, warned in ((55.0, False), (100.0, True)):
        cam = Camera(np.array([[50.0, 0, W / 2], [0, fy, H / 2], [0, 0, 1]]), np.zeros(5), H, W)
        save_calibration(seq / "camera_calibration.yaml", Calibration(cam))
        got = [w for w in open_recording(seq, **NO_ROBOT).warnings if "focal lengths" in w]
        assert len(got) == warned
    assert got[0].startswith(f"{seq / 'camera_calibration.yaml'}: K1's focal lengths fx = 50, fy = 100 px "
                             "differ by a factor 0.5")


def test_a_baseline_with_the_right_camera_on_the_left_is_warned_about(tmp_path):
    """T's sign flipped (or the images swapped) moved a simulated stereo run's tip 1.5 -> 30 px
    with exit 0: a warning naming T; the dVRK's T = (-5, 0, 0.17) mm says nothing."""
    from graphtrack.io.consistency import left_of_left

    assert left_of_left([5e-3, 0, 1.7e-4]) and not left_of_left([-5e-3, 0, 1.7e-4])
    assert not left_of_left([1e-3, -5e-3, 0])           # a vertical rig: not judged
    seq = write_meta(tmp_path / "seq")
    write_folder(seq, make_frames(2))
    cam = Camera(np.array([[50.0, 0, W / 2], [0, 50.0, H / 2], [0, 0, 1]]), np.zeros(5), H, W)
    for tx, warned in ((-5e-3, False), (5e-3, True)):
        save_calibration(seq / "camera_calibration.yaml", Calibration(cam, cam, np.eye(3), np.array([tx, 0, 1.7e-4])))
        got = [w for w in open_recording(seq, **NO_ROBOT).warnings if "to the left of the left one" in w]
        assert len(got) == warned and (not warned or got[0].startswith(f"{seq / 'camera_calibration.yaml'}: T = [5.0"))


def test_video_beside_frames_is_noted_as_unread(tmp_path):
    seq = write_meta(tmp_path / "seq")
    write_folder(seq, make_frames(2))
    (seq / "video.mp4").write_bytes(b"x")
    got = [w for w in open_recording(seq, **NO_ROBOT).warnings if "video.mp4" in w]
    assert got == [f"{seq / 'video.mp4'}: not read: frames/ holds the images (a recording has one or the other)"]


def test_jaw_readings_for_a_robot_without_gripper_are_noted(tmp_path):
    """The jaw is ignored (it was a joint_count skip of every frame); a robot.json that forgot
    has_gripper would place the tip as if the jaws were closed, so the note says so."""
    seq = write_meta(tmp_path / "seq")
    (seq / "robot.json").write_text((seq / "robot.json").read_text().replace('"has_gripper": true',
                                                                           '"has_gripper": false'))
    write_folder(seq, make_frames(2))
    rec = open_recording(seq)
    assert [w for w in rec.warnings if "jaw" in w] == [
        f"{seq}: the recording has jaw readings but {seq / 'robot.json'} has no has_gripper: the jaw is ignored "
        "(a tool with jaws needs \"has_gripper\": true, or its tip is placed as if they were closed)"]
    # ignored: each frame's q is the DH joints alone, which is what the kinematics takes
    frames = list(rec.frames())
    assert rec.has_jaw and not rec.uses_jaw and len(frames) == 2
    for f in frames:
        assert not isinstance(f, FrameError) and np.isnan(f.jaw) and f.q.shape == (rec.robot.n_joints,)
        check_joints(rec.robot, f.q)


def test_two_bags_name_a_split_recording(tmp_path):
    seq = bag_seq(tmp_path, name="rec_0.bag")
    write_bag(seq / "rec_1.bag", make_frames(2))
    with pytest.raises(InputError, match=r"2 bags \(rec_0\.bag, rec_1\.bag\); .*--split"):
        open_recording(seq, **NO_ROBOT)
