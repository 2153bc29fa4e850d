"""One synthetic world with exact ground truth, built from the geometry alone.

Used by the tests and benchmarks of every estimator (particle filter,
fixed-lag smoother, batch) and by :mod:`graphtrack.eval.consistency`; no
renderer, no detector.

Scene: the PSM with a Large Needle Driver at the joint centre ``Q0``; an
undistorted 1280 x 1024 camera with f = 1100 px and the principal point at
the image centre; the nominal hand-eye E_0 (camera_T_base) puts the camera
``distance`` = 0.12 m from a point 2 cm up the shaft from the wrist, looking
at it from the side, slightly above and from the wrist's end.

Truth: E_true = Exp(b, w) . E_0 (:func:`graphtrack.geometry.se3.bw_to_matrix`:
left, camera-frame; b in m, w in rad), so x = (b, w) is the correction an
estimator started at E_0 must find; in a sequence the error optionally
follows a random walk of per-frame std ``walk_sigma`` (m, rad), the
estimators' own motion model.

Observations of one frame seen through E (all pixels in the full-size,
undistorted image):

- pixel sets (the pixel models): per contour generator of the shaft (the two
  limbs, edge i on limb i), points drawn uniformly along the axis on
  ``span`` (m along the shaft's axis from the wrist, negative = up the
  shaft) projected exactly, Gaussian noise ``pixel_noise`` px along the
  limb line's normal, then a fraction ``outliers`` replaced by uniform stray
  pixels in the pixels' bounding box grown by 60 px; pixels outside the
  image are dropped;
- lines (the polar models): (rho, theta) of the two projected limbs, plus
  Gaussian noise ``line_noise`` = (px, rad);
- markers: the marker points facing the camera (outward normal from the shaft
  axis towards the camera). ``marker_model="disc"`` (the factors' model,
  :func:`graphtrack.robot.features.marker_discs`): a marker with a radius is
  a painted disc on the shaft and is seen at the centroid of its image;
  ``"point"`` (the particle filter's model): every marker at the projection
  of its centre. Gaussian noise ``marker_noise`` px per coordinate.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from graphtrack.detect.base import POLAR_MODELS, Observation
from graphtrack.geometry.camera import Camera
from graphtrack.geometry.cylinder import contour_generators, project_cylinder
from graphtrack.geometry.painted_marker import disc_centroid
from graphtrack.geometry.se3 import bw_to_matrix, invert, matrix_to_bw
from graphtrack.geometry.shaft_end import end_pixel
from graphtrack.io.context import TrackingContext
from graphtrack.io.frame import Frame
from graphtrack.robot.features import base_features, marker_discs
from graphtrack.robot.psm import psm_large_needle_driver
from graphtrack.sim.stereo import rig, right_camera, to_right

#: Joint centre of the trajectory (6 DH joints in rad / m, then the jaw in rad).
Q0 = np.array([0.15, -0.10, 0.14, 0.40, 0.15, -0.10, 0.40])

#: Default hand-eye error (b in m, w in rad) of a sequence: 4.1 mm / 1.6 deg.
HANDEYE_ERROR = np.array([0.003, -0.002, 0.002, 0.02, -0.015, 0.01])

#: Default shaft span seen by the pixel sets, m along the axis from the wrist.
SPAN = (-0.06, -0.004)

#: Stray pixels fall in the pixels' bounding box grown by this many px.
OUTLIER_MARGIN = 60.0

MARKER_MODELS = ("disc", "point")


def make_camera(width: int = 1280, height: int = 1024, f: float = 1100.0) -> Camera:
    """Undistorted pinhole camera, square pixels of focal length f (px), centred principal point."""
    K = np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])
    return Camera(K, np.zeros(5), height, width)


def look_at(robot, q=Q0, distance: float = 0.12) -> np.ndarray:
    """camera_T_base (4x4) with the camera ``distance`` m from the shaft 2 cm up from the
    wrist, looking at that point, the shaft running across the image."""
    F = base_features(robot, np.asarray(q, float))
    p0, d = F.shaft_p0[0], F.shaft_d[0]
    target = p0 - 0.02 * d
    side = np.cross(d, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    up = np.cross(side, d)
    view = 0.85 * side + 0.35 * up - 0.4 * d
    view /= np.linalg.norm(view)
    C = target + distance * view
    z = (target - C) / distance
    x = np.cross(z, d)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    W = np.eye(4)
    W[:3, :3] = np.stack([x, y, z], 1)
    W[:3, 3] = C
    return invert(W)


class Scene(NamedTuple):
    """robot, camera and the nominal hand-eye E0 (camera_T_base, 4x4)."""

    robot: object
    camera: Camera
    E0: np.ndarray

    @property
    def ctx(self):
        """The estimators' TrackingContext (robot, camera, E0)."""
        return TrackingContext(self.robot, self.camera, self.E0)

    def true_E(self, handeye_error=HANDEYE_ERROR) -> np.ndarray:
        """E_true = Exp(b, w) . E0 for the left error x = (b m, w rad)."""
        return bw_to_matrix(np.asarray(handeye_error, float)) @ self.E0


def make_scene(width: int = 1280, height: int = 1024, f: float = 1100.0, distance: float = 0.12) -> Scene:
    """The world's robot, camera and nominal hand-eye (:func:`look_at` at ``Q0``)."""
    robot = psm_large_needle_driver()
    return Scene(robot, make_camera(width, height, f), look_at(robot, Q0, distance))


def joint_trajectory(n: int, fps: float = 30.0, amplitude: float = 1.0, start: int = 0) -> np.ndarray:
    """(n, 7) joints of frames start ... start + n - 1: Q0 + a_j sin(2 pi f_j t + j), t = k / fps s.

    Amplitudes (rad, m for joint 3) 0.05, 0.04, 0.01, 0.4, 0.2, 0.2, 0.2 times
    ``amplitude``; frequencies 0.07-0.23 Hz: every joint moves smoothly, the
    largest step at 30 fps is 2 pi 0.05 0.4 / 30 = 4.2 mrad (joint 4)."""
    t = (start + np.arange(n)) / fps
    amp = amplitude * np.array([0.05, 0.04, 0.01, 0.4, 0.2, 0.2, 0.2])
    freq = np.array([0.11, 0.07, 0.13, 0.05, 0.17, 0.19, 0.23])
    return Q0 + amp * np.sin(2 * np.pi * freq * t[:, None] + np.arange(7))


def random_handeye_error(rng: np.random.Generator, b_mm: float, w_deg: float) -> np.ndarray:
    """A left error (b m, w rad) of magnitudes b_mm / w_deg in uniformly random directions."""
    u, v = rng.standard_normal(3), rng.standard_normal(3)
    return np.concatenate([u / np.linalg.norm(u) * b_mm * 1e-3, v / np.linalg.norm(v) * np.radians(w_deg)])


@dataclass
class SynthFrame:
    """One frame: joints q (7,), the true E (4x4), and its exact (+ noise) observations:
    pixels (per edge (m_i, 2) px), lines ((2, 2) rho px, theta rad), markers ((N, 2) px);
    valid: the shaft's projection is not degenerate; shaft_end: (k, 4) the shaft's end
    and its image direction (``Observation.shaft_end``), k = 0 unless asked for."""

    index: int
    stamp: float
    q: np.ndarray
    E_true: np.ndarray
    pixels: list
    lines: np.ndarray
    markers: np.ndarray
    valid: bool
    shaft_end: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))

    def observation(self, model: str = "line-intensities", markers: bool = True) -> Observation:
        """The estimators' input for ``model``: lines for the polar models, else pixel sets;
        edge_ids 0, 1 (edge i lies on limb i)."""
        mk = self.markers if markers else np.zeros((0, 2))
        if model in POLAR_MODELS:
            return Observation(model, lines=self.lines, markers=mk, edge_ids=np.arange(2),
                               shaft_end=self.shaft_end.copy())
        return Observation(model, pixels=self.pixels, markers=mk, edge_ids=np.arange(len(self.pixels)),
                           shaft_end=self.shaft_end.copy())

    def frame(self):
        """The estimators' Frame (index, stamp, no image, DH joints, jaw)."""
        return Frame(self.index, self.stamp, None, self.q[:6], self.q[6])


def observe(scene: Scene, q: np.ndarray, E: np.ndarray, rng: np.random.Generator, index: int = 0,
            stamp: float = 0.0, pixels_per_edge: int = 250, pixel_noise: float = 1.0, outliers: float = 0.0,
            line_noise: tuple[float, float] = (0.0, 0.0), marker_noise: float = 0.0, span=SPAN,
            marker_model: str = "disc", shaft_end_noise: float | None = None) -> SynthFrame:
    """Observations of joints q seen through E (module docstring); rng draws all noise.
    ``shaft_end_noise`` (px, None: no shaft end): observe the shaft's end
    (:mod:`graphtrack.geometry.shaft_end`) with this noise along the shaft's image."""
    if marker_model not in MARKER_MODELS:
        raise ValueError(f"marker_model {marker_model!r}: one of {MARKER_MODELS}")
    robot, cam = scene.robot, scene.camera
    q = np.asarray(q, float)
    F = base_features(robot, q).transformed(E)
    p0, d, r = F.shaft_p0[0], F.shaft_d[0], F.shaft_r[0]
    rho, theta, valid = project_cylinder(p0, d, r, cam.K)
    gens = contour_generators(p0, d, r)                     # (2, 3)
    pixels = []
    for i in range(2):
        tt = rng.uniform(span[0], span[1], pixels_per_edge)
        u = cam.project_undistorted(gens[i] + tt[:, None] * d)
        nrm = np.array([np.cos(theta[i]), np.sin(theta[i])])
        if pixel_noise > 0:
            u = u + rng.normal(0.0, pixel_noise, len(u))[:, None] * nrm
        n_out = int(round(outliers * len(u)))
        if n_out:
            lo, hi = u.min(0) - OUTLIER_MARGIN, u.max(0) + OUTLIER_MARGIN
            u[rng.choice(len(u), n_out, replace=False)] = rng.uniform(lo, hi, (n_out, 2))
        inside = (u[:, 0] >= 0) & (u[:, 0] < cam.width) & (u[:, 1] >= 0) & (u[:, 1] < cam.height)
        pixels.append(u[inside])
    lines = np.stack([rho + rng.normal(0, line_noise[0], 2) if line_noise[0] else rho,
                      theta + rng.normal(0, line_noise[1], 2) if line_noise[1] else theta], -1)
    pts = F.points
    axis_pt = p0 + ((pts - p0) @ d)[:, None] * d
    facing = np.sum((pts - axis_pt) * (-pts), axis=1) > 0    # outward normal towards the camera
    mk = cam.project_undistorted(pts) if len(pts) else np.zeros((0, 2))
    discs = marker_discs(robot, F) if marker_model == "disc" else None
    if discs is not None:
        is_disc = np.any(discs[1] != 0, axis=(1, 2))
        mk[is_disc] = disc_centroid(discs[0][is_disc], discs[1][is_disc], cam.K)
    mk = mk[facing]
    if marker_noise > 0 and len(mk):
        mk = mk + rng.normal(0, marker_noise, mk.shape)
    end = np.zeros((0, 4))
    seen = None if shaft_end_noise is None or robot.shaft_features[0].end is None else \
        end_pixel(F.shaft_end[0], d, r, cam.K)
    if seen is not None:
        end = np.concatenate([seen[0] + rng.normal(0.0, shaft_end_noise) * seen[1], seen[1]])[None]
    return SynthFrame(index, stamp, q, E, pixels, lines, mk, bool(valid), end)


class Sequence(NamedTuple):
    """A synthetic recording: the scene's robot, camera, nominal E0, and the frames."""

    robot: object
    camera: Camera
    E0: np.ndarray
    frames: list

    @property
    def ctx(self):
        return TrackingContext(self.robot, self.camera, self.E0)

    @property
    def right_frames(self) -> None:
        """No right image (:class:`StereoSequence` has them): one attribute for both kinds."""
        return None


def sequence(n: int, seed: int = 0, fps: float = 30.0, handeye_error=HANDEYE_ERROR,
             walk_sigma: tuple[float, float] = (0.0, 0.0), scene: Scene | None = None, amplitude: float = 1.0,
             start: int = 0, **observe_kw) -> Sequence:
    """n frames (start ... start + n - 1, stamps k / fps s) on :func:`joint_trajectory`.

    The true E of the first frame is Exp(handeye_error) . E0; with walk_sigma
    (m, rad) each later one is Exp(step) . E_{k-1}, step ~ N(0, diag(walk_sigma^2))
    per axis. One rng (``seed``) draws the walk and all observation noise;
    ``observe_kw`` go to :func:`observe`."""
    rng = np.random.default_rng(seed)
    scene = Scene(*scene) if scene is not None else make_scene()
    Q = joint_trajectory(n, fps, amplitude, start)
    E = scene.true_E(handeye_error)
    frames = []
    for i in range(n):
        if i and (walk_sigma[0] or walk_sigma[1]):
            step = np.concatenate([rng.normal(0, walk_sigma[0], 3), rng.normal(0, walk_sigma[1], 3)])
            E = bw_to_matrix(step) @ E
        k = start + i
        frames.append(observe(scene, Q[i], E, rng, index=k, stamp=k / fps, **observe_kw))
    return Sequence(scene.robot, scene.camera, scene.E0, frames)


class StereoSequence(NamedTuple):
    """:func:`sequence`'s recording seen by a stereo rig: the left Sequence's fields,
    the right camera (undistorted pixels share its K2), right_T_left (4x4, m) and the
    right image's frames (same q; their E_true is the right camera's right_T_left . E_true)."""

    robot: object
    camera: Camera
    E0: np.ndarray
    frames: list
    right: Camera
    right_T_left: np.ndarray
    right_frames: list

    @property
    def ctx(self):
        return TrackingContext(self.robot, self.camera, self.E0, self.right, self.right_T_left)


def stereo_sequence(n: int, seed: int = 0, scene: Scene | None = None, extrinsics=None, **kw) -> StereoSequence:
    """:func:`sequence` (n, seed, scene, ``kw``: its keywords and :func:`observe`'s),
    whose left frames are exactly those of ``sequence(n, seed, ...)``, plus the right
    image's: the right camera of :func:`graphtrack.sim.stereo.right_camera` and the rig
    ``extrinsics`` = (R, T m) (default :func:`graphtrack.sim.stereo.rig`: 5 mm, 2 deg), its
    noise drawn from its own rng (seed ``seed`` + 10**6)."""
    left = sequence(n, seed=seed, scene=scene, **kw)
    C = to_right(*(extrinsics if extrinsics is not None else rig()))
    cam_r = right_camera(left.camera)
    obs_kw = {k: v for k, v in kw.items() if k not in ("fps", "handeye_error", "walk_sigma", "amplitude", "start")}
    rng = np.random.default_rng(seed + 10**6)
    view = Scene(left.robot, cam_r, left.E0)
    right = [observe(view, f.q, C @ f.E_true, rng, index=f.index, stamp=f.stamp, **obs_kw) for f in left.frames]
    return StereoSequence(*left, cam_r, C, right)


def pose_error(E_est: np.ndarray, E_true: np.ndarray) -> tuple[float, float]:
    """(translation mm, rotation deg) of the left error Log(E_est E_true^-1) (camera frame)."""
    D = matrix_to_bw(E_est @ invert(E_true))
    return float(np.linalg.norm(D[:3]) * 1000), float(np.degrees(np.linalg.norm(D[3:])))
