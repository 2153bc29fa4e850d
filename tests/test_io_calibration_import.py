"""graphtrack calibration: ROS camera_info YAMLs and the dVRK camera registration into the
recording's calibration files; OpenCV's stereoRectify and projectPoints are the oracles."""
import json

import cv2
import numpy as np
import pytest
import yaml

from graphtrack.cli import main
from graphtrack.errors import InputError
from graphtrack.geometry.camera import load_calibration
from graphtrack.io import calibration_import as ci
from graphtrack.io.handeye import load_handeye

W, H = 960, 540
K1 = np.array([[800.0, 0, 470], [0, 805, 275], [0, 0, 1]])
K2 = np.array([[810.0, 0, 490], [0, 808, 265], [0, 0, 1]])
D1 = np.array([-0.21, 0.11, 1e-3, -2e-3, 0.01])
D2 = np.array([-0.19, 0.09, -1e-3, 1e-3, 0.0])
R_TRUE = cv2.Rodrigues(np.array([0.01, -0.03, 0.005]))[0]
T_TRUE_M = np.array([-0.0051, 0.0002, 0.0003])      # the right camera 5.1 mm to the right


def ros_yaml(path, K, D, R, P, name):
    """A camera_info YAML in camera_calibration_parsers' layout."""
    doc = {"image_width": W, "image_height": H, "camera_name": name,
           "camera_matrix": {"rows": 3, "cols": 3, "data": K.ravel().tolist()},
           "distortion_model": "plumb_bob",
           "distortion_coefficients": {"rows": 1, "cols": len(D), "data": np.ravel(D).tolist()},
           "rectification_matrix": {"rows": 3, "cols": 3, "data": R.ravel().tolist()},
           "projection_matrix": {"rows": 3, "cols": 4, "data": P.ravel().tolist()}}
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


@pytest.fixture
def stereo(tmp_path):
    """left.yaml, right.yaml as a ROS stereo calibration writes them (OpenCV's rectification),
    and OpenCV's R1, P2."""
    R1, R2, P1, P2, *_ = cv2.stereoRectify(K1, D1, K2, D2, (W, H), R_TRUE, T_TRUE_M.reshape(3, 1), alpha=0)
    left = ros_yaml(tmp_path / "left.yaml", K1, D1, R1, P1, "left")
    right = ros_yaml(tmp_path / "right.yaml", K2, D2, R2, P2, "right")
    return left, right, R1, P2


def test_raw_stereo_recovers_the_extrinsics_and_projects_as_opencv(stereo):
    left, right, *_ = stereo
    calib = ci.calibration_from_ros(ci.read_ros_camera(left), ci.read_ros_camera(right))
    np.testing.assert_allclose(calib.R, R_TRUE, atol=1e-9)
    np.testing.assert_allclose(calib.T, T_TRUE_M, atol=1e-12)
    np.testing.assert_allclose(calib.left.K, K1)
    np.testing.assert_allclose(calib.right.dist, D2)
    X = np.array([[0.01, -0.004, 0.09], [-0.012, 0.006, 0.12]])
    want = cv2.projectPoints(X, cv2.Rodrigues(R_TRUE)[0], T_TRUE_M, K2, D2)[0].reshape(-1, 2)
    np.testing.assert_allclose(calib.project_right(X), want, atol=1e-6)


def test_rectified_pair_projects_as_the_projection_matrices(stereo):
    left, right, R1, P2 = stereo
    calib = ci.calibration_from_ros(ci.read_ros_camera(left), ci.read_ros_camera(right), rectified=True)
    np.testing.assert_allclose(calib.R, np.eye(3))
    assert np.all(calib.left.dist == 0) and np.all(calib.right.dist == 0)
    X = np.array([[0.01, -0.004, 0.09], [-0.012, 0.006, 0.12]])   # in the left rectified frame
    uvw = np.c_[X, np.ones(2)] @ P2.T
    np.testing.assert_allclose(calib.project_right(X), uvw[:, :2] / uvw[:, 2:], atol=1e-9)
    # the baseline: 5.1 mm and a little, as the extrinsics' length
    assert np.linalg.norm(calib.T) == pytest.approx(np.linalg.norm(T_TRUE_M), rel=1e-9)


def registration_json(path, T):
    # as dvrk_camera_registration writes it: a brace, a "base-frame" line, a brace
    data = {"reference-frame": "left_camera", "transform": np.asarray(T).tolist()}
    path.write_text("{\n" + '"base-frame": ' + json.dumps(data) + "\n}\n")
    return path


def test_cli_writes_both_files_and_the_registration_into_the_raw_left_frame(stereo, tmp_path, capsys):
    left, right, R1, _ = stereo
    rect_T_base = np.eye(4)
    rect_T_base[:3, :3] = cv2.Rodrigues(np.array([2.2, 0.3, -0.4]))[0]
    rect_T_base[:3, 3] = [0.02, -0.01, 0.11]
    reg = registration_json(tmp_path / "PSM2-registration-open-cv.json", rect_T_base)
    seq = tmp_path / "seq"
    assert main(["calibration", "--out", str(seq), "--ros", str(left), str(right),
                 "--dvrk-registration", str(reg)]) == 0
    assert "PSM2" in capsys.readouterr().err
    calib = load_calibration(seq / "camera_calibration.yaml")
    np.testing.assert_allclose(calib.T, T_TRUE_M, atol=1e-12)
    E = load_handeye(seq / "handeye.yaml", "PSM2")
    # a base-frame point: where the rectified left camera sees it, the raw left camera sees it turned by R1^T
    X = np.array([0.01, 0.02, -0.03, 1.0])
    np.testing.assert_allclose(E @ X, np.r_[R1.T @ (rect_T_base @ X)[:3], 1.0], atol=1e-9)
    assert not list(seq.glob("*.partial"))
    # written files are not replaced without --overwrite
    assert main(["calibration", "--out", str(seq), "--ros", str(left)]) == 2
    assert "already exists" in capsys.readouterr().err


def test_rectified_keeps_the_registration_as_measured(stereo, tmp_path):
    left, right, *_ = stereo
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.01, 0.1]
    reg = registration_json(tmp_path / "reg.json", T)
    seq = tmp_path / "seq"
    assert main(["calibration", "--out", str(seq), "--ros", str(left), str(right), "--rectified",
                 "--dvrk-registration", str(reg), "--arm", "PSM3"]) == 0
    np.testing.assert_allclose(load_handeye(seq / "handeye.yaml", "PSM3"), T, atol=1e-12)


def test_swapped_files_and_unsupported_models_name_the_file(stereo, tmp_path):
    left, right, *_ = stereo
    with pytest.raises(InputError, match="right.yaml.*a right .second. camera's"):
        ci.calibration_from_ros(ci.read_ros_camera(right), ci.read_ros_camera(left))
    doc = yaml.safe_load(left.read_text())
    doc["distortion_model"] = "equidistant"
    bad = tmp_path / "fisheye.yaml"
    bad.write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match="fisheye.yaml: distortion_model 'equidistant'"):
        ci.read_ros_camera(bad)
    del doc["projection_matrix"]
    doc["distortion_model"] = "plumb_bob"
    bad.write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match="fisheye.yaml: missing field 'projection_matrix'"):
        ci.read_ros_camera(bad)


def test_bad_registrations_exit_2_with_nothing_written(stereo, tmp_path, capsys):
    left, *_ = stereo
    seq = tmp_path / "seq"
    skew = np.eye(4)
    skew[0, 1] = 0.5
    reg = registration_json(tmp_path / "PSM1-reg.json", skew)
    assert main(["calibration", "--out", str(seq), "--ros", str(left), "--dvrk-registration", str(reg)]) == 2
    assert "not a rigid transform" in capsys.readouterr().err
    # a registration in millimetres read as metres: 110 m from the base, refused with the unit named
    T = np.eye(4)
    T[:3, 3] = [20.0, -10.0, 110.0]
    reg = registration_json(tmp_path / "PSM1-mm.json", T)
    assert main(["calibration", "--out", str(seq), "--ros", str(left), "--dvrk-registration", str(reg)]) == 2
    err = capsys.readouterr().err
    assert "handeye.yaml" in err and "--registration-unit" in err and ".partial" not in err
    assert not seq.exists() or not any(seq.iterdir())
    assert main(["calibration", "--out", str(seq), "--ros", str(left), "--dvrk-registration", str(reg),
                 "--registration-unit", "mm"]) == 0
    assert np.linalg.norm(load_handeye(seq / "handeye.yaml", "PSM1")[:3, 3]) == pytest.approx(np.sqrt(20 ** 2 + 10 ** 2 + 110 ** 2) / 1000)
    reg2 = registration_json(tmp_path / "registration.json", np.eye(4))
    assert main(["calibration", "--out", str(tmp_path / "s2"), "--dvrk-registration", str(reg2)]) == 2
    assert "--arm" in capsys.readouterr().err


def write_camera_info_bag(path, cams, ros2=False):
    """A bag with one CameraInfo message per (topic, K, D, R, P), as a camera driver publishes it."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    T = ts.types
    stamp = T["builtin_interfaces/msg/Time"](sec=1, nanosec=0)
    header = (T["std_msgs/msg/Header"](stamp=stamp, frame_id="cam") if ros2
              else T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="cam"))
    roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    typ = "sensor_msgs/msg/CameraInfo"
    if ros2:
        from rosbags.rosbag2 import Writer
        writer, ser = Writer(path, version=8), ts.serialize_cdr
    else:
        from rosbags.rosbag1 import Writer
        writer, ser = Writer(path), ts.serialize_ros1
    with writer:
        for topic, K, D, R, P in cams:
            c = writer.add_connection(topic, typ, typestore=ts)
            fields = dict(zip("dkrp" if ros2 else "DKRP", (np.asarray(D, float), K.ravel(), R.ravel(), P.ravel())))
            msg = T[typ](header=header, height=H, width=W, distortion_model="plumb_bob", binning_x=0, binning_y=0,
                         roi=roi, **fields)
            writer.write(c, 1_000_000_000, ser(msg, typ))
    return path


@pytest.mark.parametrize("ros2", [False, True])
def test_bag_camera_info_gives_the_yamls_calibration(stereo, tmp_path, ros2):
    left, right, R1, P2 = stereo
    L, Rr = (ci.read_ros_camera(p) for p in (left, right))
    bag = write_camera_info_bag(tmp_path / ("rec" if ros2 else "rec.bag"),
                                [("/jhu_daVinci/left/camera_info", L.K, L.D, L.R, L.P),
                                 ("/jhu_daVinci/right/camera_info", Rr.K, Rr.D, Rr.R, Rr.P)], ros2)
    seq = tmp_path / "seq"
    assert main(["calibration", "--out", str(seq), "--bag", str(bag)]) == 0
    calib = load_calibration(seq / "camera_calibration.yaml")
    np.testing.assert_allclose(calib.R, R_TRUE, atol=1e-9)
    np.testing.assert_allclose(calib.T, T_TRUE_M, atol=1e-12)
    # named topics; a topic the bag lacks is named in the error
    cams, topics = ci.read_bag_cameras(bag, ["/jhu_daVinci/left/camera_info"])
    assert len(cams) == 1 and np.allclose(cams[0].K, K1) and topics == ["/jhu_daVinci/left/camera_info"]
    with pytest.raises(InputError, match="no sensor_msgs/msg/CameraInfo topic /stereo/left/camera_info"):
        ci.read_bag_cameras(bag, ["/stereo/left/camera_info"])


def test_an_uncalibrated_camera_info_is_refused(tmp_path):
    bag = write_camera_info_bag(tmp_path / "raw.bag", [("/cam/camera_info", np.zeros(9), [], np.eye(3), np.zeros(12))])
    with pytest.raises(InputError, match="camera_matrix is all zero"):
        ci.read_bag_cameras(bag)


@pytest.mark.parametrize("flags", [0, cv2.CALIB_ZERO_DISPARITY])
def test_vertical_pair_and_shifted_principal_points(tmp_path, flags):
    """A vertical pair (OpenCV puts the baseline in P2[1,3]), with and without equal
    principal points, recovers R and T; a right camera's file alone is refused."""
    T = np.array([0.0002, -0.0049, 0.0004])
    R1, R2, P1, P2, *_ = cv2.stereoRectify(K1, D1, K2, D2, (W, H), R_TRUE, T.reshape(3, 1), flags=flags, alpha=0.5)
    assert abs(P2[1, 3]) > abs(P2[0, 3])
    left = ci.read_ros_camera(ros_yaml(tmp_path / "l.yaml", K1, D1, R1, P1, "l"))
    right = ci.read_ros_camera(ros_yaml(tmp_path / "r.yaml", K2, D2, R2, P2, "r"))
    calib = ci.calibration_from_ros(left, right)
    np.testing.assert_allclose(calib.R, R_TRUE, atol=1e-9)
    np.testing.assert_allclose(calib.T, T, atol=1e-12)
    with pytest.raises(InputError, match="r.yaml: its projection_matrix holds a baseline"):
        ci.calibration_from_ros(right)


def test_mono_yaml_as_image_geometry_reads_it(tmp_path):
    """No distortion coefficients is no distortion; an all-zero R is the identity and an
    all-zero P no projection (a raw mono camera needs neither; --rectified needs P)."""
    path = ros_yaml(tmp_path / "ost.yaml", K1, [], np.zeros((3, 3)), np.zeros((3, 4)), "mono")
    cam = ci.read_ros_camera(path)
    calib = ci.calibration_from_ros(cam)
    np.testing.assert_array_equal(calib.left.dist, np.zeros(5))
    np.testing.assert_array_equal(cam.R, np.eye(3))
    with pytest.raises(InputError, match="ost.yaml: projection_matrix is all zero; --rectified needs it"):
        ci.calibration_from_ros(cam, rectified=True)
    ros_yaml(path, K1, [0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.02, 0.0], np.eye(3), np.zeros((3, 4)), "mono")
    with pytest.raises(InputError, match=r"k4 k5 k6 \(0, 0.02, 0\)"):
        ci.read_ros_camera(path)


def test_binned_or_cropped_camera_info_is_refused(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    typ = "sensor_msgs/msg/CameraInfo"
    header = T["std_msgs/msg/Header"](seq=0, stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="")
    for name, binning, roi in (("binned", 2, (0, 0, 0, 0)), ("cropped", 0, (100, 50, 400, 640))):
        bag = tmp_path / f"{name}.bag"
        with Writer(bag) as w:
            c = w.add_connection("/left/camera_info", typ, typestore=ts)
            msg = T[typ](header=header, height=H, width=W, distortion_model="plumb_bob", D=D1, K=K1.ravel(),
                         R=np.eye(3).ravel(), P=np.c_[K1, np.zeros(3)].ravel(), binning_x=binning, binning_y=binning,
                         roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=roi[0], y_offset=roi[1], height=roi[2],
                                                                   width=roi[3], do_rectify=False))
            w.write(c, 1_000_000_000, ts.serialize_ros1(msg, typ))
        with pytest.raises(InputError, match="binned or cropped"):
            ci.read_bag_cameras(bag)


def test_cli_refusals_are_one_line_exit_2(stereo, tmp_path, capsys):
    left, right, *_ = stereo
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert main(["calibration", "--out", str(afile), "--ros", str(left)]) == 2
    assert "not a folder" in capsys.readouterr().err
    reg = registration_json(tmp_path / "PSM2-registration-open-cv.json", np.eye(4))
    assert main(["calibration", "--out", str(tmp_path / "s"), "--dvrk-registration", str(reg), "--arm", "PSM1"]) == 2
    assert "the registration of PSM2, but --arm PSM1" in capsys.readouterr().err
    dvrk = registration_json(tmp_path / "PSM2-registration-dVRK.json", np.eye(4))
    assert main(["calibration", "--out", str(tmp_path / "s"), "--dvrk-registration", str(dvrk)]) == 2
    assert "PSM2-registration-open-cv.json" in capsys.readouterr().err
    empty = write_camera_info_bag(tmp_path / "none.bag", [])
    assert main(["calibration", "--out", str(tmp_path / "s"), "--bag", str(empty)]) == 2
    assert "no camera_info messages" in capsys.readouterr().err
    assert main(["calibration", "--out", str(tmp_path / "s"), "--ros", str(left), "--registration-unit", "mm"]) == 2
    assert "--registration-unit describes --dvrk-registration's file" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_a_recording_assembled_from_ros_and_dvrk_files_tracks_as_the_original(tmp_path):
    """A simulated stereo recording's calibration, written out as ROS camera_calibration
    and dvrk_camera_registration would (OpenCV's rectification), comes back through
    `graphtrack calibration` and tracks to the same trajectory."""
    import csv
    import shutil

    from graphtrack.sim.simulate import simulate

    src = simulate(tmp_path / "rec", "tissue", frames=4, seed=3, size=(270, 480), progress=False, form="folder",
                   stereo=True)
    calib, E = load_calibration(src / "camera_calibration.yaml"), load_handeye(src / "handeye.yaml")
    w, h = calib.left.width, calib.left.height
    R1, R2, P1, P2, *_ = cv2.stereoRectify(calib.left.K, calib.left.dist, calib.right.K, calib.right.dist, (w, h),
                                           calib.R, calib.T.reshape(3, 1), alpha=0)
    for name, cam, R, P in (("left", calib.left, R1, P1), ("right", calib.right, R2, P2)):
        doc = {"image_width": w, "image_height": h, "camera_matrix": {"data": cam.K.ravel().tolist()},
               "distortion_model": "plumb_bob", "distortion_coefficients": {"data": cam.dist.tolist()},
               "rectification_matrix": {"data": R.ravel().tolist()}, "projection_matrix": {"data": P.ravel().tolist()}}
        (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(doc))
    rect = np.eye(4)
    rect[:3, :3] = R1
    reg = registration_json(tmp_path / "PSM1-registration-open-cv.json", rect @ E)
    seq = tmp_path / "seq"
    shutil.copytree(src, seq)
    for f in ("camera_calibration.yaml", "handeye.yaml"):
        (seq / f).unlink()
    assert main(["calibration", "--out", str(seq), "--ros", str(tmp_path / "left.yaml"), str(tmp_path / "right.yaml"),
                 "--dvrk-registration", str(reg)]) == 0
    runs = []
    for rec in (src, seq):
        out = tmp_path / f"run-{rec.name}"
        assert main(["track", str(rec), "--estimator", "kinematics", "--out", str(out), "--quiet"]) == 0
        rows = list(csv.DictReader((out / "trajectory.csv").open()))
        runs.append(np.array([[float(r[k]) for k in ("tx", "ty", "tz", "qx", "qy", "qz", "qw", "tip_u", "tip_v")]
                              for r in rows]))
    np.testing.assert_allclose(runs[1], runs[0], atol=1e-9)


def test_a_suspicious_baseline_is_said_where_it_is_written(stereo, tmp_path, capsys):
    """The right camera's projection with the baseline's sign flipped: written (it may be
    a rig wired that way) with the warning track would give, at the step that made it."""
    left, right, *_ = stereo
    doc = yaml.safe_load(right.read_text())
    P = np.array(doc["projection_matrix"]["data"]).reshape(3, 4)
    P[0, 3] = -P[0, 3]
    doc["projection_matrix"]["data"] = P.ravel().tolist()
    flipped = tmp_path / "right_flipped.yaml"
    flipped.write_text(yaml.safe_dump(doc, sort_keys=False))
    assert main(["calibration", "--out", str(tmp_path / "seq"), "--ros", str(left), str(flipped)]) == 0
    err = capsys.readouterr().err
    assert "warning:" in err and "puts the right camera to the left of the left one" in err
    assert main(["calibration", "--out", str(tmp_path / "ok"), "--ros", str(left), str(right)]) == 0
    assert "warning" not in capsys.readouterr().err
    doc = yaml.safe_load(right.read_text())                  # the baseline in cm: 0.51 "mm"
    P = np.array(doc["projection_matrix"]["data"]).reshape(3, 4)
    P[0, 3] /= 10
    doc["projection_matrix"]["data"] = P.ravel().tolist()
    (tmp_path / "right_cm.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    assert main(["calibration", "--out", str(tmp_path / "cm"), "--ros", str(left), str(tmp_path / "right_cm.yaml")]) == 0
    assert "under 2 mm" in capsys.readouterr().err


def test_a_missing_registration_is_said_before_its_arm(stereo, tmp_path, capsys):
    left, *_ = stereo
    missing = tmp_path / "handeye_registration.json"      # a name that does not give the arm
    assert main(["calibration", "--out", str(tmp_path / "seq"), "--ros", str(left),
                 "--dvrk-registration", str(missing)]) == 2
    assert capsys.readouterr().err.strip().endswith(f"{missing}: file not found")
