"""handeye.yaml, labels.csv, trajectory.csv/.tum: round trips, conventions, bad input."""
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from graphtrack.errors import InputError
from graphtrack.io.handeye import load_handeye, save_handeye
from graphtrack.io.labels import read_labels, write_labels
from graphtrack.io.trajectory import COLUMNS, TrajectoryRow, TrajectoryWriter, read_trajectory


def random_pose(rng):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng.integers(1 << 30)).as_matrix()
    T[:3, 3] = rng.normal(scale=0.1, size=3)
    return T


# -- handeye.yaml ---------------------------------------------------------------------------
def test_handeye_units_and_rotation(tmp_path):
    p = tmp_path / "handeye.yaml"
    p.write_text("PSM1_tvec: [10.0, -20.0, 150.0]\nPSM1_rvec: [0.1, -0.2, 0.3]\n")
    T = load_handeye(p)
    np.testing.assert_allclose(T[:3, 3], [0.010, -0.020, 0.150], atol=1e-15)
    np.testing.assert_allclose(T[:3, :3], Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix(), atol=1e-14)
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])


def test_handeye_roundtrip(tmp_path):
    T = random_pose(np.random.default_rng(1))
    save_handeye(tmp_path / "h.yaml", T)
    text = (tmp_path / "h.yaml").read_text()
    assert "PSM1_tvec" in text and "PSM1_rvec" in text
    np.testing.assert_allclose(load_handeye(tmp_path / "h.yaml"), T, atol=1e-12)


@pytest.mark.parametrize("change, match", [
    (lambda T: np.r_[np.c_[T[:3, :3], 1000 * T[:3, 3]], T[3:]], "mm from the base"),   # a translation in mm
    (lambda T: np.diag([2.0, 2.0, 2.0, 1.0]), "not a finite rigid"),   # a scaled, not a rotation
    (lambda T: T @ np.diag([1.0, 1.0, -1.0, 1.0]), "not a finite rigid"),   # a reflection
    (lambda T: np.where(np.eye(4, dtype=bool), np.nan, T), "not a finite rigid"),
    (lambda T: T[:3], "not a finite rigid"),
])
def test_save_handeye_refuses_what_load_handeye_would(tmp_path, change, match):
    T = random_pose(np.random.default_rng(1))
    with pytest.raises(InputError, match=match):
        save_handeye(tmp_path / "h.yaml", change(T))
    assert not (tmp_path / "h.yaml").exists()


def test_handeye_single_arm_any_prefix_and_opencv_header(tmp_path):
    p = tmp_path / "handeye.yaml"
    p.write_text("%YAML:1.0\nPSM2_tvec: [1, 2, 3]\nPSM2_rvec: {data: [0, 0, 0]}\n")
    np.testing.assert_allclose(load_handeye(p)[:3, 3], [0.001, 0.002, 0.003])
    np.testing.assert_allclose(load_handeye(p, arm="PSM2")[:3, 3], [0.001, 0.002, 0.003])


def test_handeye_named_arm_must_exist_and_several_arms_need_a_choice(tmp_path):
    p = tmp_path / "handeye.yaml"
    p.write_text("PSM2_tvec: [1, 2, 3]\nPSM2_rvec: [0, 0, 0]\n")
    with pytest.raises(InputError, match=r"missing key 'PSM1_tvec'.* keys for PSM2 only.*"
                                         r"rename PSM2_tvec and PSM2_rvec to PSM1_tvec and PSM1_rvec"):
        load_handeye(p, arm="PSM1")
    p.write_text("ECM_tvec: [1, 2, 3]\nECM_rvec: [0, 0, 0]\n")   # never told to rename another device's
    with pytest.raises(InputError, match=r"missing key 'PSM1_tvec'.* keys for ECM only; .* \(an arm's: PSM1, "
                                         r"PSM2, PSM3; an ECM's or another device's registration is another"):
        load_handeye(p, arm="PSM1")
    p.write_text("psm2_tvec: [1, 2, 3]\npsm2_rvec: [0, 0, 0]\n")     # lower case: read as it is
    np.testing.assert_allclose(load_handeye(p)[:3, 3], [0.001, 0.002, 0.003])
    p.write_text("PSM1_tvec: [1, 2, 3]\nPSM1_rvec: [0, 0, 0]\nPSM3_tvec: [4, 5, 6]\nPSM3_rvec: [0, 0, 0]\n")
    with pytest.raises(InputError, match=r"several arms \(PSM1, PSM3\).*--arm"):
        load_handeye(p)
    np.testing.assert_allclose(load_handeye(p, arm="PSM3")[:3, 3], [0.004, 0.005, 0.006])


@pytest.mark.parametrize("text,needle", [
    ("PSM1_rvec: [0, 0, 0]\n", "PSM1_tvec"),
    ("PSM1_tvec: [1, 2, 3]\n", "PSM1_rvec"),
    ("PSM1_tvec: [1, two, 3]\nPSM1_rvec: [0, 0, 0]\n", "PSM1_tvec"),
    ("PSM1_tvec: [1, 2]\nPSM1_rvec: [0, 0, 0]\n", "PSM1_tvec"),
    ("PSM1_tvec: [1, 2, 3]\nPSM1_rvec: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n", "a rotation matrix?"),
    ("PSM1_tvec: [1, 2, .nan]\nPSM1_rvec: [0, 0, 0]\n", "PSM1_tvec"),
    ("PSM1_tvec: [1, 2, 3]\nPSM1_rvec: [0, .inf, 0]\n", "PSM1_rvec"),
    ("PSM2_tvec: [1, 2, 3]\nPSM2_rvec: [0, 0, 0]\nPSM3_tvec: [1, 2, 3]\n", "several arms"),
    ("ECM_tvec: [1, 2, 3]\nECM_rvec: [0, 0, 0]\n", "keys 'ECM_tvec' / 'ECM_rvec' name no arm graphtrack tracks"),
    ("PSM4_tvec: [1, 2, 3]\nPSM4_rvec: [0, 0, 0]\n", "(PSM1, PSM2, PSM3)"),
    ("[1, 2, 3]\n", "mapping"),
    ("PSM1_tvec: [1, 2\n", "YAML"),
])
def test_handeye_bad(tmp_path, text, needle):
    p = tmp_path / "handeye.yaml"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        load_handeye(p)
    assert "handeye.yaml" in str(e.value) and needle in str(e.value)


def test_handeye_missing_file(tmp_path):
    with pytest.raises(InputError, match="handeye.yaml: file not found"):
        load_handeye(tmp_path / "handeye.yaml")


# -- labels.csv -----------------------------------------------------------------------------
def test_labels_roundtrip(tmp_path):
    labels = {0: np.array([512.3, 301.8]), 7: np.array([1 / 3, 2 / 3]), 3: np.array([0.0, 959.5])}
    write_labels(tmp_path / "labels.csv", labels)
    lines = (tmp_path / "labels.csv").read_text().splitlines()
    assert lines[0] == "frame,u,v" and lines[1].startswith("0,") and lines[3].startswith("7,")
    back = read_labels(tmp_path / "labels.csv")
    assert sorted(back) == [0, 3, 7]
    for k in labels:  # full precision
        assert back[k].tolist() == labels[k].tolist()


def test_labels_nan_row_is_unlabelled(tmp_path):
    (tmp_path / "labels.csv").write_text("frame,u,v\n0,1.5,2.5\n1,nan,nan\n2,,\n")
    assert list(read_labels(tmp_path / "labels.csv")) == [0]


@pytest.mark.parametrize("text,needle", [
    ("frame,x,y\n0,1,2\n", "header"),
    ("frame,u,v\n0,1\n", "line 2"),
    ("frame,u,v\n0,a,2\n", "line 2"),
    ("frame,u,v\n0,1,2\n0,3,4\n", "frame 0 labelled twice"),
    ("frame,u,v\n-1,1,2\n", "negative"),
])
def test_labels_bad(tmp_path, text, needle):
    (tmp_path / "labels.csv").write_text(text)
    with pytest.raises(InputError) as e:
        read_labels(tmp_path / "labels.csv")
    assert "labels.csv" in str(e.value) and needle in str(e.value)


# -- trajectory.csv / .tum --------------------------------------------------------------------
HEADER = "frame,stamp,tx,ty,tz,qx,qy,qz,qw,tip_u,tip_v,ms"


def test_trajectory_header_exact(tmp_path):
    with TrajectoryWriter(tmp_path):
        pass
    assert (tmp_path / "trajectory.csv").read_text() == HEADER + "\n"
    assert (tmp_path / "trajectory.tum").read_text() == ""
    assert ",".join(COLUMNS) == HEADER
    with TrajectoryWriter(tmp_path / "x", extra_columns=["std_bx", "n_feat"]):
        pass
    assert (tmp_path / "x" / "trajectory.csv").read_text() == HEADER + ",std_bx,n_feat\n"


def test_trajectory_quaternion_convention_and_tum(tmp_path):
    rng = np.random.default_rng(2)
    poses = [random_pose(rng) for _ in range(20)]
    with TrajectoryWriter(tmp_path) as w:
        for i, E in enumerate(poses):
            w.write(i, 1000.0 + i / 30, E, (100.5 + i, 200.25), 12.5)
    rows = (tmp_path / "trajectory.csv").read_text().splitlines()[1:]
    tum = (tmp_path / "trajectory.tum").read_text().splitlines()
    assert len(rows) == len(tum) == 20
    for i, (E, row, line) in enumerate(zip(poses, rows, tum)):
        f = row.split(",")
        q_ref = Rotation.from_matrix(E[:3, :3]).as_quat()  # scipy: (x, y, z, w)
        q_ref = q_ref if q_ref[3] >= 0 else -q_ref
        q = np.array(f[5:9], dtype=float)
        np.testing.assert_allclose(q, q_ref, atol=1e-12)
        assert [float(v) for v in f[2:5]] == E[:3, 3].tolist()  # full precision translation
        assert int(f[0]) == i and float(f[1]) == 1000.0 + i / 30
        assert float(f[9]) == 100.5 + i and float(f[10]) == 200.25 and float(f[11]) == 12.5
        assert line.split() == [f[1]] + f[2:9]  # stamp tx ty tz qx qy qz qw


def test_trajectory_flushes_every_row(tmp_path):
    w = TrajectoryWriter(tmp_path)
    w.write(0, 0.0, np.eye(4), None, 1.0)
    # not closed: the row must already be on disk
    assert len((tmp_path / "trajectory.csv").read_text().splitlines()) == 2
    assert len((tmp_path / "trajectory.tum").read_text().splitlines()) == 1
    w.close()


def test_trajectory_read_roundtrip_extras_and_nan_tip(tmp_path):
    rng = np.random.default_rng(3)
    poses = [random_pose(rng) for _ in range(5)]
    with TrajectoryWriter(tmp_path, extra_columns=["std_bx", "label"]) as w:
        for i, E in enumerate(poses):
            tip = None if i == 2 else np.array([10.0 * i, np.pi])
            w.write(i, 5.0 + i, E, tip, 0.1 * i, {"std_bx": 1e-3 * i, "label": "a"} if i != 4 else {})
    t = read_trajectory(tmp_path / "trajectory.csv")
    assert t["frame"].tolist() == list(range(5)) and t["stamp"].tolist() == [5.0, 6.0, 7.0, 8.0, 9.0]
    np.testing.assert_allclose(t["E"], np.stack(poses), atol=1e-14)
    assert np.all(np.isnan(t["tip"][2])) and t["tip"][3].tolist() == [30.0, np.pi]
    assert t["ms"][1] == 0.1
    assert t["extras"]["std_bx"][1] == 1e-3 and np.isnan(t["extras"]["std_bx"][4])
    assert t["extras"]["label"].tolist() == ["a", "a", "a", "a", ""]


def test_trajectory_rewrite_all_then_append(tmp_path):
    with TrajectoryWriter(tmp_path) as w:
        for i in range(4):
            w.write(i, float(i), np.eye(4), None, 1.0)
        E = np.eye(4)
        E[:3, 3] = [0.1, 0.2, 0.3]
        w.rewrite_all([TrajectoryRow(i, float(i), E, (1.0, 2.0), 3.0) for i in range(3)]
                      + [{"frame": 3, "stamp": 3.0, "E": E}])
        w.write(4, 4.0, E, None, 1.0)
    t = read_trajectory(tmp_path / "trajectory.csv")
    assert t["frame"].tolist() == [0, 1, 2, 3, 4]
    np.testing.assert_allclose(t["E"][:, :3, 3], np.tile([0.1, 0.2, 0.3], (5, 1)))
    assert len((tmp_path / "trajectory.tum").read_text().splitlines()) == 5
    assert not list(tmp_path.glob("*.tmp"))


def test_trajectory_reads_truth_with_empty_ms(tmp_path):
    p = tmp_path / "truth.csv"
    p.write_text(HEADER + "\n0,1.5,0.1,0.2,0.3,0,0,0,1,320.5,240.25,\n1,1.6,0.1,0.2,0.3,0,0,1,0,,,\n")
    t = read_trajectory(p)
    assert np.isnan(t["ms"]).all() and t["tip"][0].tolist() == [320.5, 240.25] and np.isnan(t["tip"][1]).all()
    np.testing.assert_allclose(t["E"][1][:3, :3], np.diag([-1.0, -1.0, 1.0]), atol=1e-15)


@pytest.mark.parametrize("text,needle", [
    ("frame,stamp,tx\n", "header must start with"),
    (HEADER + "\n0,1,2\n", "line 2"),
    (HEADER + "\n0,x,0,0,0,0,0,0,1,0,0,0\n", "line 2"),
])
def test_trajectory_read_bad(tmp_path, text, needle):
    p = tmp_path / "trajectory.csv"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        read_trajectory(p)
    assert "trajectory.csv" in str(e.value) and needle in str(e.value)


def test_trajectory_writer_rejects_undeclared_extra(tmp_path):
    with TrajectoryWriter(tmp_path, extra_columns=["a"]) as w:
        with pytest.raises(ValueError, match="extra_columns"):
            w.write(0, 0.0, np.eye(4), None, 1.0, {"b": 1.0})


def test_trajectory_nan_pose_written_as_nan(tmp_path):
    with TrajectoryWriter(tmp_path) as w:
        w.write(0, 0.0, np.full((4, 4), np.nan), None, math.nan)
    row = (tmp_path / "trajectory.csv").read_text().splitlines()[1].split(",")
    assert row[2:] == ["nan"] * 10
