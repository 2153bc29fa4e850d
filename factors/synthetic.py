"""Observations synthesised from the geometry, for tests and benchmarks.

A fixed camera looks at the PSM's shaft near the wrist from ~12 cm; the joints
move smoothly; the true lumped error E_t = hand-eye error . E_0, optionally
with a random walk (the motion model's own Gaussian increments in the left,
camera-frame (b, w) parameterisation). Per frame:

- shaft pixels: points on the two contour generators (shaft from the wrist
  back ``shaft_length`` m) projected with the TRUE E, Gaussian noise
  ``pixel_noise`` px across the line, plus a fraction ``outliers`` of uniform
  stray pixels in the tool's neighbourhood;
- lines: (rho, theta) of the true limbs (+ noise) for the polar models;
- markers: the markers facing the camera seen through the true E (+ noise): a
  painted disc (a point feature with a radius) at the centroid of its image,
  a point at its projection.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphtrack.geometry.camera import Camera
from graphtrack.geometry.cylinder import contour_generators, project_cylinder
from graphtrack.geometry.painted_marker import disc_centroid
from graphtrack.geometry.se3 import bw_to_matrix, invert
from graphtrack.robot.features import base_features, marker_discs
from graphtrack.robot.psm import psm_large_needle_driver

Q0 = np.array([0.15, -0.10, 0.14, 0.40, 0.15, -0.10, 0.40])


@dataclass
class SynthFrame:
    index: int
    stamp: float
    q: np.ndarray          # full joint vector (DH joints + jaw)
    E_true: np.ndarray     # 4x4
    pixels: list           # per edge (m_i, 2)
    lines: np.ndarray      # (k, 2)
    markers: np.ndarray    # (N, 2)
    valid: bool


def make_scene(width: int = 1280, height: int = 1024, f: float = 1100.0, distance: float = 0.12):
    """robot, camera (no distortion), E_0 (camera-from-base) looking at the shaft near the wrist."""
    robot = psm_large_needle_driver()
    K = np.array([[f, 0.0, width / 2 - 0.5], [0.0, f, height / 2 - 0.5], [0.0, 0.0, 1.0]])
    cam = Camera(K, np.zeros(5), height, width)
    F = base_features(robot, Q0)
    p0, d = F.shaft_p0[0], F.shaft_d[0]
    target = p0 - 0.02 * d
    side = np.cross(d, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    up = np.cross(side, d)
    view = (0.85 * side + 0.35 * up - 0.4 * d)
    view /= np.linalg.norm(view)
    C = target + distance * view
    z = (target - C) / distance
    x = np.cross(z, d)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    W = np.eye(4)
    W[:3, :3] = np.stack([x, y, z], 1)
    W[:3, 3] = C
    return robot, cam, invert(W)


def joint_trajectory(n: int, fps: float = 30.0, amplitude: float = 1.0) -> np.ndarray:
    """(n, 7) smooth joint motion around Q0."""
    t = np.arange(n) / fps
    amp = amplitude * np.array([0.05, 0.04, 0.01, 0.4, 0.2, 0.2, 0.2])
    freq = np.array([0.11, 0.07, 0.13, 0.05, 0.17, 0.19, 0.23])
    return Q0 + amp * np.sin(2 * np.pi * freq * t[:, None] + np.arange(7))


def observe(robot, cam: Camera, q: np.ndarray, E: np.ndarray, rng: np.random.Generator,
            pixels_per_edge: int = 250, pixel_noise: float = 1.0, outliers: float = 0.0,
            line_noise: tuple[float, float] = (0.0, 0.0), marker_noise: float = 0.0,
            shaft_length: float = 0.06):
    """Pixels per edge, lines (2, 2) and markers (N, 2) of one frame seen through E."""
    F = base_features(robot, q).transformed(E)
    p0, d, r = F.shaft_p0[0], F.shaft_d[0], F.shaft_r[0]
    rho, theta, valid = project_cylinder(p0, d, r, cam.K)
    gens = contour_generators(p0, d, r)                     # (2, 3)
    pixels = []
    for i in range(2):
        tt = rng.uniform(-shaft_length, -0.004, pixels_per_edge)
        X = gens[i] + tt[:, None] * d
        u = cam.project_undistorted(X)
        nrm = np.array([np.cos(theta[i]), np.sin(theta[i])])
        u = u + rng.normal(0.0, pixel_noise, len(u))[:, None] * nrm if pixel_noise > 0 else u
        n_out = int(round(outliers * len(u)))
        if n_out:
            lo, hi = u.min(0) - 60, u.max(0) + 60
            u[rng.choice(len(u), n_out, replace=False)] = rng.uniform(lo, hi, (n_out, 2))
        inside = (u[:, 0] >= 0) & (u[:, 0] < cam.width) & (u[:, 1] >= 0) & (u[:, 1] < cam.height)
        pixels.append(u[inside])
    lines = np.stack([rho + rng.normal(0, line_noise[0], 2) if line_noise[0] else rho,
                      theta + rng.normal(0, line_noise[1], 2) if line_noise[1] else theta], -1)
    # markers facing the camera: a painted disc (a point feature with a radius) at the
    # centroid of its image, a point at its projection
    pts = F.points
    axis_pt = p0 + ((pts - p0) @ d)[:, None] * d
    normal = pts - axis_pt
    facing = np.sum(normal * (-pts), axis=1) > 0
    mk = cam.project_undistorted(pts) if len(pts) else np.zeros((0, 2))
    discs = marker_discs(robot, F)
    if discs is not None:
        is_disc = np.any(discs[1] != 0, axis=(1, 2))
        mk[is_disc] = disc_centroid(discs[0][is_disc], discs[1][is_disc], cam.K)
    mk = mk[facing]
    if marker_noise > 0 and len(mk):
        mk = mk + rng.normal(0, marker_noise, mk.shape)
    return pixels, lines, mk, bool(valid)


def sequence(n: int, seed: int = 0, fps: float = 30.0, handeye_error=(0.003, -0.002, 0.002, 0.02, -0.015, 0.01),
             walk_sigma: tuple[float, float] = (0.0, 0.0), scene=None, **observe_kw):
    """Scene + n synthetic frames. handeye_error: left (b, w) with E_true = Exp(b, w) . E_0
    (as bw_to_matrix); walk_sigma: per-frame random-walk std (m, rad) of that error."""
    rng = np.random.default_rng(seed)
    robot, cam, E0 = scene or make_scene()
    Q = joint_trajectory(n, fps)
    bw = np.asarray(handeye_error, float).copy()
    frames = []
    for k in range(n):
        if k and (walk_sigma[0] or walk_sigma[1]):
            step = np.concatenate([rng.normal(0, walk_sigma[0], 3), rng.normal(0, walk_sigma[1], 3)])
            Et = bw_to_matrix(step) @ frames[-1].E_true
        else:
            Et = bw_to_matrix(bw) @ E0
        px, ln, mk, valid = observe(robot, cam, Q[k], Et, rng, **observe_kw)
        frames.append(SynthFrame(k, k / fps, Q[k], Et, px, ln, mk, valid))
    return robot, cam, E0, frames
