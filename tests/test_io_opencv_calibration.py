"""graphtrack calibration --opencv: calibrations cv2.FileStorage saved (the writer is the
oracle) under the names OpenCV's samples use."""
import json

import cv2
import numpy as np
import pytest

from graphtrack.cli import main
from graphtrack.errors import InputError
from graphtrack.geometry.camera import load_calibration
from graphtrack.io.handeye import load_handeye
from graphtrack.io.opencv_calibration import calibration_from_opencv

W, H = 960, 540
K1 = np.array([[800.0, 0, 470], [0, 805, 275], [0, 0, 1]])
K2 = np.array([[810.0, 0, 490], [0, 808, 265], [0, 0, 1]])
D1 = np.array([[-0.21, 0.11, 1e-3, -2e-3, 0.01]])
D2 = np.array([[-0.19, 0.09, -1e-3, 1e-3, 0.0]])
R = cv2.Rodrigues(np.array([0.01, -0.03, 0.005]))[0]
T_MM = np.array([[-5.1], [0.2], [0.3]])


def storage(path, **nodes):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for k, v in nodes.items():
        if isinstance(v, tuple):         # a cv::Size-like sequence
            fs.startWriteStruct(k, cv2.FileNode_SEQ | cv2.FileNode_FLOW)
            for x in v:
                fs.write("", x)
            fs.endWriteStruct()
        else:
            fs.write(k, v)
    fs.release()
    return path


def test_stereo_sample_files_with_rectification_and_registration(tmp_path, capsys):
    """OpenCV's stereo_calib sample: intrinsics.yml (M1 D1 M2 D2) and extrinsics.yml (R T R1 R2
    P1 P2 Q), T in mm; the registration is turned by the saved R1."""
    R1, R2, P1, P2, Q, *_ = cv2.stereoRectify(K1, D1, K2, D2, (W, H), R, T_MM, alpha=0)
    intr = storage(tmp_path / "intrinsics.yml", M1=K1, D1=D1, M2=K2, D2=D2)
    extr = storage(tmp_path / "extrinsics.yml", R=R, T=T_MM, R1=R1, R2=R2, P1=P1, P2=P2, Q=Q)
    rect_T_base = np.eye(4)
    rect_T_base[:3, :3] = cv2.Rodrigues(np.array([2.0, 0.2, -0.3]))[0]
    rect_T_base[:3, 3] = [0.01, -0.02, 0.12]
    reg = tmp_path / "PSM1-registration-open-cv.json"
    reg.write_text(json.dumps({"base-frame": {"reference-frame": "left", "transform": rect_T_base.tolist()}}))
    seq = tmp_path / "seq"
    assert main(["calibration", "--out", str(seq), "--opencv", str(intr), str(extr), "--image-size", "960x540",
                 "--length-unit", "mm", "--dvrk-registration", str(reg)]) == 0
    calib = load_calibration(seq / "camera_calibration.yaml")
    np.testing.assert_allclose(calib.left.K, K1)
    np.testing.assert_allclose(calib.right.dist, D2.ravel())
    np.testing.assert_allclose(calib.R, R, atol=1e-15)
    np.testing.assert_allclose(calib.T, T_MM.ravel() / 1000)
    X = np.array([0.01, 0.02, -0.03, 1.0])
    np.testing.assert_allclose(load_handeye(seq / "handeye.yaml", "PSM1") @ X,
                               np.r_[R1.T @ (rect_T_base @ X)[:3], 1.0], atol=1e-12)
    assert "in the left camera's frame" in capsys.readouterr().err


def test_xml_with_the_functions_names_and_a_cv_size(tmp_path):
    path = storage(tmp_path / "stereo.xml", cameraMatrix1=K1, distCoeffs1=D1, cameraMatrix2=K2, distCoeffs2=D2,
                   R=R, T=T_MM / 1000, imageSize=(W, H))
    calib, R1 = calibration_from_opencv([path], unit_m=1.0)
    assert (calib.left.height, calib.left.width) == (H, W)   # cv::Size is [width, height]
    np.testing.assert_allclose(calib.T, T_MM.ravel() / 1000)
    # no R1 saved: stereoRectify's, which depends on R and T alone
    want = cv2.stereoRectify(np.eye(3), None, np.eye(3), None, (100, 80), R, T_MM)[0]
    np.testing.assert_allclose(R1, want, atol=1e-12)


def test_mono_calibration_sample_layout(tmp_path, capsys):
    """OpenCV's calibration sample writes image_width, image_height, camera_matrix,
    distortion_coefficients; no unit is needed for one camera."""
    path = storage(tmp_path / "out_camera_data.yml", image_width=W, image_height=H, camera_matrix=K1,
                   distortion_coefficients=D1, avg_reprojection_error=0.3)
    seq = tmp_path / "seq"
    assert main(["calibration", "--out", str(seq), "--opencv", str(path)]) == 0
    calib = load_calibration(seq / "camera_calibration.yaml")
    assert calib.right is None and (calib.left.height, calib.left.width) == (H, W)
    np.testing.assert_allclose(calib.left.dist, D1.ravel())


def test_refusals_name_what_is_missing(tmp_path, capsys):
    stereo = storage(tmp_path / "s.yml", M1=K1, D1=D1, M2=K2, D2=D2, R=R, T=T_MM, image_width=W, image_height=H)
    with pytest.raises(InputError, match="T is in the unit the pattern's square size was given in.*--length-unit"):
        calibration_from_opencv([stereo])
    nosize = storage(tmp_path / "n.yml", M1=K1, D1=D1)
    with pytest.raises(InputError, match="no image size.*--image-size"):
        calibration_from_opencv([nosize])
    with pytest.raises(InputError, match="no numeric node 'Kleft' \\(for K1\\)"):
        calibration_from_opencv([stereo], keys={"K1": "Kleft"}, unit_m=1e-3)
    other = storage(tmp_path / "o.yml", A=K1, B=D1, image_width=W, image_height=H)
    with pytest.raises(InputError, match="no camera matrix and distortion found.*--opencv-keys"):
        calibration_from_opencv([other])
    calib, _ = calibration_from_opencv([other], keys={"K1": "A", "D1": "B"})
    np.testing.assert_allclose(calib.left.K, K1)
    rational = storage(tmp_path / "r.yml", M1=K1, D1=np.array([[0.1, 0, 0, 0, 0, 0.3, 0, 0]]), image_width=W,
                       image_height=H)
    with pytest.raises(InputError, match="distortion terms past k3 \\(0.3; CALIB_RATIONAL_MODEL"):
        calibration_from_opencv([rational])
    # through the CLI: one line, exit 2
    assert main(["calibration", "--out", str(tmp_path / "x"), "--opencv", str(stereo)]) == 2
    assert "--length-unit" in capsys.readouterr().err
    assert main(["calibration", "--out", str(tmp_path / "x"), "--opencv", str(stereo), "--opencv-keys", "K9=M1",
                 "--length-unit", "mm"]) == 2
    assert "unknown role(s) K9" in capsys.readouterr().err
    (tmp_path / "bad.yml").write_text("%YAML:1.0\n{{{ nope\n")
    assert main(["calibration", "--out", str(tmp_path / "x"), "--opencv", str(tmp_path / "bad.yml")]) == 2
    assert "bad.yml: not a file OpenCV's FileStorage reads" in capsys.readouterr().err


@pytest.mark.parametrize("name,size", [("imageSize", (W, H)), ("ImageSize", (H, W))])
def test_a_size_node_in_either_order_centres_the_principal_point(tmp_path, name, size):
    """OpenCV writes a cv::Size as [width, height], graphtrack's ImageSize is [height, width]."""
    path = storage(tmp_path / "c.yml", M1=K1, D1=D1, **{name: size})
    calib, _ = calibration_from_opencv([path])
    assert (calib.left.height, calib.left.width) == (H, W)


def test_what_would_have_been_silently_wrong_is_refused(tmp_path):
    """Two cameras' own calibrations, fisheye models, a size other than the calibration's,
    a stale R1, names that could each be the matrix: refused, naming the cause."""
    left = storage(tmp_path / "left.yml", camera_matrix=K1, distortion_coefficients=D1, image_width=W, image_height=H)
    right = storage(tmp_path / "right.yml", camera_matrix=K2, distortion_coefficients=D2, image_width=W,
                    image_height=H)
    with pytest.raises(InputError, match="node 'camera_matrix' is also in .*left.yml, with other values"):
        calibration_from_opencv([left, right])
    fish = storage(tmp_path / "fish.yml", camera_matrix=K1, distortion_coefficients=np.zeros((4, 1)),
                   fisheye_model=1, image_width=W, image_height=H)
    with pytest.raises(InputError, match="a fisheye calibration"):
        calibration_from_opencv([fish])
    k4 = storage(tmp_path / "k4.yml", K=K1, D=np.array([[0.1, 0.01, 0.0, 0.0]]), image_width=W, image_height=H)
    with pytest.raises(InputError, match="4 distortion coefficients: a cv2.fisheye calibration"):
        calibration_from_opencv([k4])
    with pytest.raises(InputError, match="calibrated on 960x540 images, not --image-size 480x270"):
        calibration_from_opencv([left], size=(270, 480))
    R1, R2, *_ = cv2.stereoRectify(K1, D1, K2, D2, (W, H), R, T_MM)
    swapped = storage(tmp_path / "sw.yml", M1=K1, D1=D1, M2=K2, D2=D2, R=R, T=T_MM, R1=R2, R2=R1,
                      image_width=W, image_height=H)
    with pytest.raises(InputError, match="its R1 is not stereoRectify's left rectification"):
        calibration_from_opencv([swapped], unit_m=1e-3)
    both = storage(tmp_path / "both.yml", mtxL=K1, cameraMatrix1=K2, distL=D1, image_width=W, image_height=H)
    with pytest.raises(InputError, match="'cameraMatrix1', 'mtxL' could each be K1 and differ"):
        calibration_from_opencv([both])
    calib, _ = calibration_from_opencv([both], keys={"K1": "mtx_l"})     # names as blind to case as the search
    np.testing.assert_allclose(calib.left.K, K1)


def test_scalars_and_units_as_lab_scripts_write_them(tmp_path, capsys):
    """Coefficients saved as separate numbers k1, k2 do not take the K1 / K2 roles; a stray
    scalar T does not make a single camera stereo; T in squares reads with metres per unit."""
    mono = storage(tmp_path / "m.yml", camera_matrix=K1, distortion_coefficients=D1, k1=-0.21, k2=0.11, T=3.0,
                   image_width=W, image_height=H)
    calib, R1 = calibration_from_opencv([mono])
    assert calib.right is None and np.array_equal(R1, np.eye(3))
    squares = storage(tmp_path / "sq.yml", M1=K1, D1=D1, M2=K2, D2=D2, R=R, T=T_MM / 2.5, image_width=W,
                      image_height=H)
    seq = tmp_path / "seq"
    assert main(["calibration", "--out", str(seq), "--opencv", str(squares), "--length-unit", "0.0025"]) == 0
    np.testing.assert_allclose(load_calibration(seq / "camera_calibration.yaml").T, T_MM.ravel() / 1000)
    with pytest.raises(SystemExit) as e:     # argparse's own usage error: exit 2, one line
        main(["calibration", "--out", str(tmp_path / "x"), "--opencv", str(squares), "--length-unit", "-1"])
    assert e.value.code == 2 and "give m, mm, or metres per unit" in capsys.readouterr().err
