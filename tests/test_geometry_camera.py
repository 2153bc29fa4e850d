"""Camera projection and calibration loading against OpenCV as the oracle."""
import cv2
import numpy as np
import pytest

from graphtrack.errors import InputError
from graphtrack.geometry.camera import Calibration, Camera, load_calibration, save_calibration, size_mismatch_hint

K = np.array([[1000.0, 0, 481.3], [0, 995.0, 268.9], [0, 0, 1]])
D = np.array([-0.32, 0.12, 0.0011, -0.0007, -0.02])


def camera():
    return Camera(K.copy(), D.copy(), 540, 960)


def points(n=500, seed=0):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.04, 0.04, n), rng.uniform(-0.025, 0.025, n), rng.uniform(0.06, 0.2, n)])


def test_project_raw_matches_cv2_projectPoints():
    P = points()
    ref, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), K, D)
    np.testing.assert_allclose(camera().project_raw(P), ref.reshape(-1, 2), atol=1e-9)


def test_project_undistorted_matches_cv2_without_distortion():
    P = points(seed=1)
    ref, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), K, None)
    np.testing.assert_allclose(camera().project_undistorted(P), ref.reshape(-1, 2), atol=1e-9)


def test_undistort_pixels_inverts_distortion():
    cam = camera()
    P = points(seed=2)
    raw = cam.project_raw(P)
    np.testing.assert_allclose(cam.undistort_pixels(raw), cam.project_undistorted(P), atol=1e-6)
    np.testing.assert_allclose(cam.distort_pixels(cam.project_undistorted(P)), raw, atol=1e-9)


def test_undistort_image_moves_a_dot_to_its_undistorted_pixel():
    cam = camera()
    P = np.array([[0.035, 0.02, 0.1]])
    raw = cam.project_raw(P)[0]
    img = np.zeros((540, 960), np.uint8)
    cv2.circle(img, (int(round(raw[0] * 16)), int(round(raw[1] * 16))), 3 * 16, 255, -1, shift=4)
    und = cam.undistort(img)
    m = cv2.moments(und.astype(np.float32))
    centre = np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])
    assert np.linalg.norm(centre - cam.project_undistorted(P)[0]) < 0.3
    assert cam.undistort_maps() is cam.undistort_maps()  # computed once


def test_calibration_roundtrip_mono_and_stereo(tmp_path):
    cam = camera()
    save_calibration(tmp_path / "mono.yaml", Calibration(cam))
    c = load_calibration(tmp_path / "mono.yaml")
    np.testing.assert_array_equal(c.left.K, K)
    np.testing.assert_array_equal(c.left.dist, D)
    assert (c.left.height, c.left.width) == (540, 960) and c.right is None
    stereo = Calibration(cam, camera(), np.eye(3), np.array([-0.0042, 0, 0]))
    save_calibration(tmp_path / "stereo.yaml", stereo)
    text = (tmp_path / "stereo.yaml").read_text()
    assert "-4.2" in text  # millimetres on disk
    s = load_calibration(tmp_path / "stereo.yaml")
    np.testing.assert_allclose(s.T, [-0.0042, 0, 0])


@pytest.mark.parametrize("header", ["%YAML:1.0", None])   # OpenCV 4 writes the first; 5 a real directive
def test_calibration_as_opencv_filestorage_writes_it(tmp_path, header):
    """A stereoCalibrate result saved by cv2.FileStorage under the format's keys (matrices
    as !!opencv-matrix, ImageSize as a 1x2 matrix) reads as written."""
    p = tmp_path / "camera_calibration.yaml"
    R = cv2.Rodrigues(np.array([0.01, 0.02, -0.01]))[0]
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
    for key, value in (("ImageSize", np.array([[540, 960]], np.int32)), ("K1", K), ("D1", D.reshape(1, 5)),
                       ("K2", K), ("D2", D.reshape(1, 5)), ("R", R), ("T", np.array([[-4.8], [0.1], [0.2]]))):
        fs.write(key, value)
    fs.release()
    if header:
        text = p.read_text().splitlines()
        p.write_text("\n".join([header] + text[1:]) + "\n")
    c = load_calibration(p)
    np.testing.assert_array_equal(c.left.K, K)
    np.testing.assert_array_equal(c.right.dist, D)
    np.testing.assert_allclose(c.R, R, atol=1e-15)
    np.testing.assert_allclose(c.T, [-0.0048, 0.0001, 0.0002])
    assert (c.left.height, c.left.width) == (540, 960)


@pytest.mark.parametrize("text,needle", [
    ("K1: {data: [1,0,0,0,1,0,0,0,1]}\nD1: {data: [0,0,0,0,0]}\n", "ImageSize"),
    ("ImageSize: [540, 960]\nD1: {data: [0,0,0,0,0]}\n", "K1"),
    ("ImageSize: [540, 960]\nK1: {data: [1,0,0,0,1]}\nD1: {data: [0,0,0,0,0]}\n", "K1"),
    ("ImageSize: [540, 960]\nK1: {data: [1,0,0,0,1,0,0,0,x]}\nD1: {data: [0,0,0,0,0]}\n", "K1"),
    ("ImageSize: [540, 960]\nK1: {data: [800,0,480,0,800,270,0,0,1]}\nD1: {data: [.nan,0,0,0,0]}\n", "D1"),
    # K divided by the image size (fx = 800 / 960)
    ("ImageSize: [540, 960]\nK1: {data: [0.833,0,0.5,0,1.48,0.5,0,0,1]}\nD1: {data: [0,0,0,0,0]}\n",
     "K1': focal lengths 0.833, 1.48 px would see more than 168 deg"),
    ("ImageSize: [540, 960]\nK1: {data: [40,0,480,0,40,270,0,0,1]}\nD1: {data: [0,0,0,0,0]}\n",
     "K1': focal lengths 40, 40 px would see more than 168 deg"),
    ("ImageSize: [540, 960]\nK1: {data: [800,200,480,0,800,270,0,0,1]}\nD1: {data: [0,0,0,0,0]}\n",
     "K1': skew K[0,1] = 200 px is not supported"),
    ("ImageSize: [540, 960\n", "YAML"),
])
def test_bad_calibration_names_file_and_key(tmp_path, text, needle):
    p = tmp_path / "camera_calibration.yaml"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        load_calibration(p)
    assert "camera_calibration.yaml" in str(e.value) and needle in str(e.value)


def test_missing_calibration_file(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        load_calibration(tmp_path / "nope.yaml")


def test_scaled_undistort_samples_full_raw_image():
    """undistort(img, 0.5) = the undistorted image of camera.scaled(0.5), from the full raw image."""
    cam = camera()
    P = np.array([[0.03, -0.015, 0.1]])
    raw = cam.project_raw(P)[0]
    img = np.zeros((540, 960), np.uint8)
    cv2.circle(img, (int(round(raw[0] * 16)), int(round(raw[1] * 16))), 4 * 16, 255, -1, shift=4)
    small = cam.undistort(img, 0.5)
    assert small.shape == (270, 480)
    m = cv2.moments(small.astype(np.float32))
    centre = np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])
    assert np.linalg.norm(centre - cam.scaled(0.5).project_undistorted(P)[0]) < 0.3


def test_undistort_resized_is_opencvs_undistortion_of_the_reduced_camera():
    """Resize-then-undistort: a raw frame resized by 1/4 and undistorted with the reduced
    camera equals cv2.undistort with that camera's K and the same D (OpenCV's oracle),
    and puts a dot at its undistorted pixel; D = 0 returns the image itself."""
    cam = camera()
    P = np.array([[0.03, -0.015, 0.1]])
    raw = cam.project_raw(P)[0]
    img = np.zeros((540, 960), np.uint8)
    cv2.circle(img, (int(round(raw[0] * 16)), int(round(raw[1] * 16))), 8 * 16, 255, -1, shift=4)
    small = cv2.resize(img, (240, 135), interpolation=cv2.INTER_AREA)
    out = cam.undistort_resized(small)
    ref = cv2.undistort(small, cam.scaled(0.25).K, cam.dist)
    assert out.shape == (135, 240)
    assert np.abs(out.astype(int) - ref.astype(int)).max() <= 2
    m = cv2.moments(out.astype(np.float32))
    centre = np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])
    assert np.linalg.norm(centre - cam.scaled(0.25).project_undistorted(P)[0]) < 0.3
    rect = Camera(K.copy(), np.zeros(5), 540, 960)
    assert rect.undistort_resized(small) is small


# a randomized recording's camera (structured-700015): k1 = -0.11, 1419 px focal length
K_WIDE = np.array([[1418.74, 0, 475.7], [0, 1418.74, 274.0], [0, 0, 1]])
D_WIDE = np.array([-0.1108, 0.00077, -0.00097, -0.00077, 0.0])


def test_in_image_refuses_points_the_distortion_folds_into_the_image():
    """Far off the axis the plumb-bob polynomial turns back: OpenCV projects a point 72 deg
    off the axis into the image, but the camera does not image it."""
    cam = Camera(K_WIDE.copy(), D_WIDE.copy(), 540, 960)
    folded = np.array([3.0 * 0.04, -0.3 * 0.04, 0.04])
    uv, _ = cv2.projectPoints(folded[None], np.zeros(3), np.zeros(3), K_WIDE, D_WIDE)
    u, v = uv.ravel()
    assert 0 <= u <= 959 and 0 <= v <= 539            # the model's raw pixel is inside
    near = np.array([0.01, 0.005, 0.1])               # 6 deg off the axis
    outside = np.array([0.05, 0.0, 0.1])              # raw pixel x ~ 1165, beyond the right edge
    behind = np.array([0.0, 0.0, -0.1])
    assert cam.in_image(np.stack([folded, near, outside, behind])).tolist() == [False, True, False, False]


def test_in_image_without_distortion_is_the_image_rectangle():
    cam = Camera(K.copy(), np.zeros(5), 540, 960)
    rng = np.random.default_rng(3)
    P = np.stack([rng.uniform(-0.1, 0.1, (2, 50)), rng.uniform(-0.06, 0.06, (2, 50)),
                  rng.uniform(-0.02, 0.2, (2, 50))], -1)
    uv = cam.project_undistorted(P)
    expected = (P[..., 2] > 0) & (uv[..., 0] >= 0) & (uv[..., 0] <= 959) & (uv[..., 1] >= 0) & (uv[..., 1] <= 539)
    got = cam.in_image(P)
    assert got.shape == (2, 50) and 0 < expected.sum() < expected.size
    np.testing.assert_array_equal(got, expected)


def test_size_mismatch_hint():
    assert "swapped" in size_mismatch_hint((960, 540), (540, 960))
    # a crop by two rows is not "the same shape at 1 times the size"
    assert "cropped or padded" in size_mismatch_hint((272, 480), (270, 480))
    assert "at 2 times the size" in size_mismatch_hint((1080, 1920), (540, 960))
    assert "by 2)" in size_mismatch_hint((1080, 1920), (540, 960))
    assert "by 0.5)" in size_mismatch_hint((270, 480), (540, 960))
    assert size_mismatch_hint((480, 640), (540, 960)) == ""       # 4:3 against 16:9: no scale fits


def test_a_skew_is_dropped_with_a_note_by_what_it_moves(tmp_path):
    """Dropping a skew s moves the image's top and bottom rows by s (h / 2) / fy px (the
    pinhole u = fx x + s y + cx at y = +-(h / 2) / fy): up to half a pixel silently, up to
    3 px with a note, beyond refused. 1080p, fy = 1048: s = 1.5 px moves 0.77 px."""
    p = tmp_path / "camera_calibration.yaml"
    for s, moved in ((0.9, None), (1.5, 0.77)):
        p.write_text(f"ImageSize: [1080, 1920]\nK1: {{data: [1050,{s},960,0,1048,540,0,0,1]}}\n"
                     "D1: {data: [0,0,0,0,0]}\n")
        c = load_calibration(p)
        assert c.left.K[0, 1] == 0.0 and c.left.K[0, 0] == 1050
        assert c.notes == ([] if moved is None else [
            f"{p}: K1's skew K[0,1] = {s:g} px is dropped (graphtrack's camera has none): the image's top and "
            f"bottom rows move by up to {moved:.2g} px; calibrate without it"])
    p.write_text("ImageSize: [1080, 1920]\nK1: {data: [1050,6,960,0,1048,540,0,0,1]}\nD1: {data: [0,0,0,0,0]}\n")
    with pytest.raises(InputError, match=r"skew K\[0,1\] = 6 px is not supported: .* move the image's top and "
                                         r"bottom rows by 3\.09 px"):
        load_calibration(p)


def test_undistort_refuses_an_image_of_another_size():
    """The remap tables are the calibration's size: another image would come back cropped
    or padded (a 2x frame as its top-left quarter), so it is refused, naming both sizes."""
    cam = Camera(np.array([[100.0, 0, 80], [0, 100, 60], [0, 0, 1]]), np.array([0.1, 0, 0, 0, 0]), 120, 160)
    assert cam.undistort(np.zeros((120, 160, 3), np.uint8)).shape == (120, 160, 3)
    assert cam.undistort(np.zeros((120, 160), np.uint8), 0.5).shape == (60, 80)
    with pytest.raises(ValueError, match=r"shape \(240, 320, 3\).*120 x 160.*2 times the size"):
        cam.undistort(np.zeros((240, 320, 3), np.uint8))
    with pytest.raises(ValueError, match="width and height swapped"):
        cam.undistort(np.zeros((160, 120, 3), np.uint8))


@pytest.mark.parametrize("t_mm, hint", [(0.45, "centimetres by 10"), (0.004, "metres must be multiplied by 1000")])
def test_a_baseline_in_another_unit_is_named(tmp_path, t_mm, hint):
    cam = Camera(np.array([[100.0, 0, 80], [0, 100, 60], [0, 0, 1]]), np.zeros(5), 120, 160)
    save_calibration(tmp_path / "c.yaml", Calibration(cam, cam, np.eye(3), np.array([-t_mm / 1000, 0.0, 0.0])))
    with pytest.raises(InputError, match=hint):
        load_calibration(tmp_path / "c.yaml")
