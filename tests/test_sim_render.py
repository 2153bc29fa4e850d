"""Geometry of the simulator's renderer: silhouettes, markers and the truth tip are exact."""
import cv2
import numpy as np
import pytest

from graphtrack.geometry.cylinder import project_cylinder
from graphtrack.geometry.se3 import invert, transform_points
from graphtrack.robot.kinematics import link_transforms
from graphtrack.robot.psm import SHAFT_END, SHAFT_RADIUS
from graphtrack.sim.simulate import Simulation

SIZE = (360, 640)


@pytest.fixture(scope="module")
def clean():
    return Simulation("structured", 6, seed=5, size=SIZE, noise_free=True)


def _crossings(gray: np.ndarray, T: float, rows: bool):
    """Sub-pixel threshold crossings along rows (or columns): (N, 2) raw (u, v)."""
    g = gray if rows else gray.T
    a, b = g[:, :-1], g[:, 1:]
    r, c = np.nonzero((a >= T) != (b >= T))
    x = c + (a[r, c] - T) / (a[r, c] - b[r, c])
    pts = np.stack([x, r.astype(float)], -1)
    return pts if rows else pts[:, ::-1]


def test_shaft_silhouette_matches_limb_lines(clean):
    cam = clean.camera
    for i in range(3):
        img, _ = clean.render(i)
        gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(float)
        L4 = clean.L_true[i, 4]
        p0, d = L4[:3, 3], L4[:3, 2]
        rho, theta, valid = project_cylinder(p0, d, SHAFT_RADIUS, cam.K)
        assert valid
        rows = abs(np.cos(theta[0])) > abs(np.sin(theta[0]))  # line more vertical -> scan rows
        bg = float(np.median(gray[gray > 200]))
        pts = _crossings(gray, (bg + 13.0) / 2, rows)
        und = cam.undistort_pixels(pts)
        # keep the shaft body: behind the markers (> 2 cm from the shaft end), inside the image
        a = cam.project_undistorted(p0 + (SHAFT_END - 0.02) * d)
        b = cam.project_undistorted(p0 + (SHAFT_END - 0.06) * d)
        s = (und - a) @ (b - a) / ((b - a) @ (b - a))
        und, pts = und[s > 0], pts[s > 0]
        # per scan line the outermost crossings are the limbs (the highlight lies between)
        key = pts[:, 1] if rows else pts[:, 0]
        along = pts[:, 0] if rows else pts[:, 1]
        keep = []
        g = gray if rows else gray.T
        for k in np.unique(key):
            line = g[int(k)]
            idx = np.nonzero(key == k)[0]
            lo, hi = idx[np.argmin(along[idx])], idx[np.argmax(along[idx])]
            # a limb has only background outside it on the scan line (not the
            # highlight of a shaft that leaves the image)
            if np.all(line[:int(np.floor(along[lo])) + 1] > 200):
                keep.append(lo)
            if np.all(line[int(np.ceil(along[hi])):] > 200):
                keep.append(hi)
        und = und[np.unique(keep)]
        assert len(und) > 40, f"frame {i}: only {len(und)} limb points"
        dist = np.abs(np.cos(theta)[None] * und[:, :1] + np.sin(theta)[None] * und[:, 1:] - rho[None])
        err = dist.min(1)
        assert np.max(err) < 1.0, f"frame {i}: max limb error {np.max(err):.3f} px"
        assert np.median(err) < 0.3


def test_marker_centroids(clean):
    cam = clean.camera
    tested = 0
    for i in range(clean.n):
        img, _ = clean.render(i)
        hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
        mask = ((hsv[..., 0] >= 95) & (hsv[..., 0] <= 115) & (hsv[..., 1] > 120) & (hsv[..., 2] > 50))
        n, lab, stats, cents = cv2.connectedComponentsWithStats(mask.astype(np.uint8))
        L4 = clean.L_true[i, 4]
        for p in clean.robot.point_features:
            X = transform_points(L4, np.asarray(p.position))
            normal = L4[:3, :3] @ np.array([p.position[0], p.position[1], 0.0]) / SHAFT_RADIUS
            if normal @ (-X / np.linalg.norm(X)) < 0.6:
                continue  # seen too obliquely (or from behind): the blob is cut by the limb
            uv = cam.project_raw(X)
            if not (10 < uv[0] < cam.width - 10 and 10 < uv[1] < cam.height - 10):
                continue
            d = np.linalg.norm(cents[1:] - uv, axis=1)
            assert len(d) and d.min() < 1.5, f"frame {i} {p.name}: centroid off by {d.min():.2f} px"
            assert stats[1 + np.argmin(d), cv2.CC_STAT_AREA] > 10
            tested += 1
    assert tested >= 2


def test_truth_tip_and_lumped_error(clean):
    robot = clean.robot
    L = clean.E_he @ link_transforms(robot, clean.q_true)
    tip = transform_points(L[:, robot.tool_tip.link], np.asarray(robot.tool_tip.position))
    uv = clean.camera.project_raw(tip)
    assert np.max(np.abs(uv - clean.tip_uv)) < 0.5
    # E_t . FK_4(readings) = true camera_T_link4
    lhs = clean.E_t @ link_transforms(robot, clean.q_read)[:, 4]
    assert np.allclose(lhs, L[:, 4], atol=1e-12)
    # the rendered image is tool-coloured just behind the tip (the jaw is there)
    img, visible = clean.render(0)
    assert visible


def test_noisy_truth_defines_E_from_readings():
    sim = Simulation("tissue", 30, seed=2, size=(180, 320))
    robot = sim.robot
    assert not np.allclose(sim.q_read, sim.q_true)
    true4 = sim.E_he @ link_transforms(robot, sim.q_true)[:, 4]
    assert np.allclose(sim.E_t @ link_transforms(robot, sim.q_read)[:, 4], true4, atol=1e-12)
    # nominal hand-eye carries a few mm and 1-3 degrees of error
    D = sim.E_nominal @ invert(sim.E_he)
    ang = np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1)))
    assert 1.0 <= ang <= 3.0 and 0.002 <= np.linalg.norm(D[:3, 3]) <= 0.005
    # joints 1-3 biased by up to ~1 deg / ~1 mm, wrist joints only slightly noisy
    err = sim.q_read - sim.q_true
    assert np.max(np.abs(err[:, :2])) < np.radians(1.5) and np.max(np.abs(err[:, 2])) < 0.002
    assert np.max(np.abs(err[:, 3:6])) < np.radians(1.0)
