"""Cylinder limb lines against an independent oracle: cv2.projectPoints of points
sampled on the contour generators (where the viewing ray is tangent)."""
import cv2
import numpy as np

from graphtrack.geometry.cylinder import project_cylinder
from graphtrack.geometry.lines import pixel_residual


def tangent_points(p0, d, r, rng, n=8):
    """Points on the cylinder whose viewing ray is tangent, found WITHOUT the
    closed form: on the circle around the axis through the point of closest
    approach, the surface normal must be perpendicular to the viewing ray;
    solve cos/sin by bisection-free root finding of f(phi) = (X(phi)) . nrm(phi)."""
    d = d / np.linalg.norm(d)
    a = np.cross(d, [1.0, 0, 0])
    if np.linalg.norm(a) < 1e-3:
        a = np.cross(d, [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(d, a)
    out = []
    for t in rng.uniform(-0.03, 0.03, n):
        c = p0 + t * d
        phis = np.linspace(0, 2 * np.pi, 3601)
        nrm = np.cos(phis)[:, None] * a + np.sin(phis)[:, None] * b
        f = np.sum((c + r * nrm) * nrm, axis=1)  # ray . normal
        for i in np.where(np.sign(f[:-1]) != np.sign(f[1:]))[0]:
            lo, hi = phis[i], phis[i + 1]
            for _ in range(60):  # bisection to machine precision
                mid = (lo + hi) / 2
                nm = np.cos(mid) * a + np.sin(mid) * b
                fm = np.dot(c + r * nm, nm)
                nl = np.cos(lo) * a + np.sin(lo) * b
                if np.sign(fm) == np.sign(np.dot(c + r * nl, nl)):
                    lo = mid
                else:
                    hi = mid
            nm = np.cos(lo) * a + np.sin(lo) * b
            out.append(c + r * nm)
    return np.array(out)


def test_limb_lines_against_projectPoints_1000_random_cylinders():
    rng = np.random.default_rng(42)
    checked = 0
    worst = 0.0
    while checked < 1000:
        K = np.array([[rng.uniform(400, 1500), 0, rng.uniform(300, 700)],
                      [0, rng.uniform(400, 1500), rng.uniform(200, 400)], [0, 0, 1]])
        p0 = np.array([rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rng.uniform(0.05, 0.3)])
        d = rng.normal(size=3)
        r = rng.uniform(0.002, 0.01)
        rho, theta, valid = project_cylinder(p0, d, r, K)
        if not valid:
            continue
        X = tangent_points(p0, d, r, rng, n=3)
        X = X[X[:, 2] > 0.01]
        if len(X) == 0:
            continue
        uv, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, None)
        uv = uv.reshape(-1, 2)
        res = np.abs(np.stack([pixel_residual(uv, rho[j], theta[j]) for j in range(2)], 1))  # (P, 2)
        dist = res.min(axis=1)  # each tangent point lies on one of the two limb lines
        worst = max(worst, dist.max())
        # both lines are hit
        assert len(set(np.argmin(res, axis=1))) == 2 or len(X) < 2
        checked += 1
    assert worst < 1e-6, worst


def test_vectorised_matches_single_and_flags_degenerate():
    rng = np.random.default_rng(0)
    K = np.array([[800.0, 0, 480], [0, 800, 270], [0, 0, 1]])
    p0 = rng.normal(size=(50, 3)) * 0.03 + [0, 0, 0.15]
    d = rng.normal(size=(50, 3))
    rho, theta, valid = project_cylinder(p0, d, 0.004, K)
    for i in range(50):
        r1, t1, v1 = project_cylinder(p0[i], d[i], 0.004, K)
        np.testing.assert_allclose(r1, rho[i])
        np.testing.assert_allclose(t1, theta[i])
        assert v1 == valid[i]
    # camera inside the cylinder
    _, _, v = project_cylinder(np.array([0.001, 0, 0.002]), np.array([0, 1.0, 0]), 0.004, K)
    assert not v
    # shaft behind the camera
    rho, theta, v = project_cylinder(np.array([0.0, 0.02, -0.1]), np.array([1.0, 0, 0]), 0.004, K)
    assert not v and np.all(np.isfinite(rho)) and np.all(np.isfinite(theta))
    # seen end-on (axis along the viewing ray)
    rho, theta, v = project_cylinder(np.array([0.0, 0.0, 0.1]), np.array([0, 0, 1.0]), 0.004, K)
    assert not v and np.all(np.isfinite(rho))
    assert np.all(theta >= 0) and np.all(theta < np.pi)
