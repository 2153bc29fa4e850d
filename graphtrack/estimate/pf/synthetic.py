"""A synthetic PSM scene with exact ground truth, built from the geometry alone.

Used by the particle filter's tests and benchmark (no renderer, no detector):
the true shaft limb lines are projected from E_true, pixels are sampled along
the visible part of each contour generator (Gaussian noise normal to the line,
plus uniform outliers), markers facing the camera are projected.

Convention as in the filter: E_true = bw_to_matrix(x_true) . E_0, so x_true
(b in m, w in rad) is the correction the filter must find.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphtrack.detect.base import POLAR_MODELS, Observation
from graphtrack.io.context import TrackingContext
from graphtrack.geometry.camera import Camera
from graphtrack.geometry.cylinder import contour_generators, project_cylinder
from graphtrack.geometry.se3 import bw_to_matrix, invert, make_transform, matrix_to_bw
from graphtrack.robot.features import base_features
from graphtrack.robot.psm import SHAFT_END, psm_large_needle_driver

Q_CENTRE = np.array([0.0, 0.0, 0.15, 0.0, 0.0, 0.0, 0.3])


def make_camera(width: int = 1280, height: int = 1024, f: float = 1000.0) -> Camera:
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])
    return Camera(K, np.zeros(5), height, width)


def look_at_E(robot, q=Q_CENTRE, distance: float = 0.12,
              view=(0.8, 0.3, 0.5)) -> np.ndarray:
    """camera_T_base with the camera ``distance`` m from the shaft near the wrist, looking at it."""
    f = base_features(robot, np.asarray(q, float))
    target = f.shaft_p0[0] - 0.02 * f.shaft_d[0]  # 2 cm up the shaft from the wrist
    v = np.asarray(view, float)
    v /= np.linalg.norm(v)
    c = target + distance * v
    z = -v
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return invert(make_transform(np.stack([x, y, z], 1), c))


@dataclass
class Scene:
    ctx: TrackingContext
    E_true: np.ndarray
    x_true: np.ndarray

    def joints(self, t: int, amplitude: float = 1.0) -> np.ndarray:
        """A smooth joint trajectory around Q_CENTRE (frame t)."""
        a = amplitude
        return Q_CENTRE + a * np.array([0.15 * np.sin(0.05 * t), 0.12 * np.sin(0.037 * t + 1),
                                        0.02 * np.sin(0.043 * t), 1.2 * np.sin(0.031 * t),
                                        0.3 * np.sin(0.06 * t), 0.3 * np.sin(0.05 * t + 2), 0.0])

    def truth(self, q: np.ndarray):
        """True shaft lines (2, 2), marker pixels (visible only, (M, 2)), edge pixels sampler."""
        K = self.ctx.camera.K
        f = base_features(self.ctx.robot, q).transformed(self.E_true)
        p0, d, r = f.shaft_p0[0], f.shaft_d[0], f.shaft_r[0]
        rho, theta, valid = project_cylinder(p0, d, r, K)
        m = f.points
        radial = m - p0 - ((m - p0) @ d)[:, None] * d
        vis = np.sum(radial * m, 1) < 0
        px = self.ctx.camera.project_undistorted(m[vis])
        return np.stack([rho, theta], -1), px, (p0, d, r), bool(valid)

    def observation(self, q: np.ndarray, model: str, rng: np.random.Generator,
                    n_pixels: int = 250, pixel_noise: float = 1.0, outliers: float = 0.05,
                    line_noise=(0.0, 0.0), marker_noise: float = 0.0,
                    markers: bool = True) -> Observation:
        """Observation for reading q: ``n_pixels`` per edge for the pixel models."""
        lines, mk, (p0, d, r), _ = self.truth(q)
        mk = mk + marker_noise * rng.standard_normal(mk.shape) if markers else np.zeros((0, 2))
        if model in POLAR_MODELS:
            ln = lines + rng.standard_normal(lines.shape) * np.asarray(line_noise)
            return Observation(model, lines=ln, markers=mk, edge_ids=np.arange(2))
        cam = self.ctx.camera
        gens = contour_generators(p0, d, r)  # (2, 3)
        sets = []
        for i in range(2):
            t = rng.uniform(-0.09, SHAFT_END, n_pixels)
            P = cam.project_undistorted(gens[i] + t[:, None] * d)
            n = np.array([np.cos(lines[i, 1]), np.sin(lines[i, 1])])
            P = P + pixel_noise * rng.standard_normal(n_pixels)[:, None] * n
            k = rng.random(n_pixels) < outliers
            P[k] = P[k] + rng.uniform(-60, 60, (k.sum(), 2))
            inside = (P[:, 0] >= 0) & (P[:, 0] < cam.width) & (P[:, 1] >= 0) & (P[:, 1] < cam.height)
            sets.append(P[inside])
        return Observation(model, pixels=sets, markers=mk, edge_ids=np.arange(2))


def make_scene(b_err=(0.003, 0.0, 0.0), w_err_deg=(0.0, 2.0, 0.0), seed: int | None = None,
               b_mm: float | None = None, w_deg: float | None = None) -> Scene:
    """Scene whose prior E_0 is off the truth by the correction x_true = (b_err, w_err).

    With ``seed``, b_mm and w_deg, the error direction is random with the given magnitudes.
    """
    robot = psm_large_needle_driver()
    cam = make_camera()
    E_true = look_at_E(robot)
    if seed is not None:
        g = np.random.default_rng(seed)
        u, v = g.standard_normal(3), g.standard_normal(3)
        b = u / np.linalg.norm(u) * b_mm / 1000.0
        w = v / np.linalg.norm(v) * np.radians(w_deg)
    else:
        b, w = np.asarray(b_err, float), np.radians(np.asarray(w_err_deg, float))
    x_true = np.concatenate([b, w])
    E0 = invert(bw_to_matrix(x_true)) @ E_true
    return Scene(TrackingContext(robot, cam, E0), E_true, x_true)


def pose_error(E_est: np.ndarray, E_true: np.ndarray) -> tuple[float, float]:
    """(translation error in mm, rotation error in deg) of E_est E_true^-1 (camera frame)."""
    D = matrix_to_bw(E_est @ invert(E_true))
    return float(np.linalg.norm(D[:3]) * 1000), float(np.degrees(np.linalg.norm(D[3:])))
