"""Camera placement, smooth joint motion, and the errors the tracker must absorb.

Units: metres, radians, seconds (frames at ``fps``).

* Nominal camera pose (:func:`look_at_workspace`): at a reference joint vector
  q0 the wrist W and shaft direction s (link 4's z) are computed; the optical
  axis makes ``view_deg`` (60-75 deg) with s (the shaft points away from the
  endoscope, never end-on), the camera sits ``distance`` from a point just
  past the wrist, and is rolled so that the shaft enters the image from an
  upper edge while the tip sits off-centre on the other side.
* True joints (:func:`true_trajectory`): q(t) = q0 + sum_k A_k sin(2 pi f_k t +
  phi_k), three low frequencies (0.02-0.25 Hz) per joint. A draw is accepted
  when in every frame the tip projects inside the image (5 % margin), the
  visible shaft is >= 1/4 of the image width long and not seen end-on;
  otherwise the amplitudes shrink by 0.8 and a new draw is made (q0 itself is
  valid by construction, so this terminates).
* Readings (:func:`readings`): q~ = q + bias(t) + white noise. Joints 1-3 carry
  slowly drifting biases (cable stretch / hysteresis): an offset plus a slow
  sinusoid plus a smoothed random walk, ~0.5-1 deg on joints 1-2 and ~1 mm on
  joint 3; the wrist joints 4-6 and the jaw carry only small white noise.
* Hand-eye error (:func:`handeye_error`): Delta = (R(w), b), |b| 2-5 mm,
  |w| 1-3 deg; the NOMINAL hand-eye written to handeye.yaml is
  Delta . E_handeye_true.
"""
from __future__ import annotations

import numpy as np

from graphtrack.geometry.se3 import bw_to_matrix, invert, transform_points
from graphtrack.robot.kinematics import link_transforms
from graphtrack.robot.psm import SHAFT_END

Q0 = np.array([0.0, 0.0, 0.13, 0.0, 0.0, 0.0, 0.5])
#: Amplitude (sum of the three sinusoids' amplitudes) per joint.
AMPLITUDE = np.array([0.13, 0.10, 0.015, 1.2, 0.6, 0.6, 0.35])


def _unit(v):
    return v / np.linalg.norm(v)


def look_at_workspace(robot, q0, distance: float, view_deg: float, azimuth: float,
                      shaft_dir_deg: float, tip_offset_px: float, f: float) -> np.ndarray:
    """camera_T_base (4x4, m) looking at the wrist at q0 (see module doc)."""
    L = link_transforms(robot, q0)
    W, s = L[4, :3, 3], L[4, :3, 2]
    P = W + 0.004 * s
    u = _unit(np.cross(s, [0.0, 0.0, 1.0]) if abs(s[2]) < 0.9 else np.cross(s, [1.0, 0, 0]))
    u = np.cos(azimuth) * u + np.sin(azimuth) * np.cross(s, u)
    th = np.radians(view_deg)
    cz = _unit(np.cos(th) * s + np.sin(th) * u)
    e1 = _unit(-(s - (s @ cz) * cz))          # image direction towards the RCM
    e2 = np.cross(cz, e1)
    ph = np.radians(shaft_dir_deg)
    cx = np.cos(ph) * e1 - np.sin(ph) * e2
    cy = np.cross(cz, cx)
    R = np.stack([cx, cy, cz])
    # tip off-centre, away from where the shaft enters: shift the camera in its plane
    o = -tip_offset_px * np.array([np.cos(ph), np.sin(ph)])
    C = P - distance * cz - (o[0] * distance / f) * cx - (o[1] * distance / f) * cy
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ C
    return T


def view_ok(robot, camera, cam_T_base, q, min_shaft_frac: float = 0.25, margin: float = 0.05):
    """Per frame (q: (N, 7)): tip inside the image and enough shaft visible."""
    L = cam_T_base @ link_transforms(robot, q)                      # (N, links, 4, 4)
    tip = transform_points(L[:, robot.tool_tip.link], np.asarray(robot.tool_tip.position))
    H, W = camera.height, camera.width
    ok = tip[:, 2] > 0.03
    uv = camera.project_raw(np.where(ok[:, None], tip, [0, 0, 1.0]))
    ok &= (uv[:, 0] > margin * W) & (uv[:, 0] < (1 - margin) * W)
    ok &= (uv[:, 1] > margin * H) & (uv[:, 1] < (1 - margin) * H)
    z = np.linspace(-0.15, SHAFT_END, 60)
    pts = L[:, 4, None, :3, 3] + z[None, :, None] * L[:, 4, None, :3, 2]  # (N, 60, 3)
    front = pts[..., 2] > 0.02
    xy = pts[..., :2] / np.where(front, pts[..., 2], 1.0)[..., None]
    inside = front & (np.abs(xy[..., 0]) < 2) & (np.abs(xy[..., 1]) < 2)
    uvs = camera.project_raw(np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], -1))
    inside &= (uvs[..., 0] >= 0) & (uvs[..., 0] < W) & (uvs[..., 1] >= 0) & (uvs[..., 1] < H)
    first = np.argmax(inside, axis=1)
    last = z.size - 1 - np.argmax(inside[:, ::-1], axis=1)
    n = np.arange(len(q))
    length = np.linalg.norm(uvs[n, last] - uvs[n, first], axis=1) * inside.any(1)
    ok &= length >= min_shaft_frac * W
    axis = L[:, 4, :3, 2]
    ray = L[:, 4, :3, 3] / np.linalg.norm(L[:, 4, :3, 3], axis=1, keepdims=True)
    ok &= np.abs(np.sum(axis * ray, 1)) < np.cos(np.radians(25))
    return ok


def sinusoids(rng, n: int, fps: float, amplitude: np.ndarray, fmin=0.02, fmax=0.25) -> np.ndarray:
    """(n, J) sum of three random sinusoids per joint with total amplitude ``amplitude``."""
    t = np.arange(n) / fps
    J = len(amplitude)
    w = rng.dirichlet(np.ones(3), size=J)                     # split of the amplitude
    f = rng.uniform(fmin, fmax, size=(J, 3))
    ph = rng.uniform(0, 2 * np.pi, size=(J, 3))
    return np.einsum("jk,tjk->tj", w * amplitude[:, None],
                     np.sin(2 * np.pi * f[None] * t[:, None, None] + ph[None]))


def true_trajectory(robot, camera, cam_T_base, q0, n: int, fps: float, rng,
                    amplitude=AMPLITUDE, tries: int = 25) -> np.ndarray:
    """(n, 7) true joints: smooth, within limits, tool in view in every frame."""
    lim = robot.joint_limits
    amp = np.asarray(amplitude, float).copy()
    for _ in range(tries):
        q = q0[None] + sinusoids(rng, n, fps, amp)
        q = np.clip(q, lim[:, 0], lim[:, 1])
        if np.all(view_ok(robot, camera, cam_T_base, q)):
            return q
        amp[:3] *= 0.8
        amp[4:6] *= 0.9
    return np.repeat(q0[None], n, 0)


def readings(rng, q: np.ndarray, fps: float, noise_free: bool = False) -> np.ndarray:
    """Noisy joint readings q~ (n, 7) for true joints q (see module doc)."""
    if noise_free:
        return q.copy()
    n = len(q)
    t = np.arange(n) / fps
    bias = np.zeros_like(q)
    scale = np.array([np.radians(0.8), np.radians(0.8), 0.001])
    for j in range(3):
        off = rng.uniform(-0.6, 0.6) * scale[j]
        A = rng.uniform(0.2, 0.4) * scale[j]
        f = 1.0 / rng.uniform(15.0, 60.0)
        walk = np.cumsum(rng.normal(0, 1, n))
        k = int(3 * fps)
        walk = np.convolve(np.pad(walk, (k, k), mode="edge"), np.ones(2 * k + 1) / (2 * k + 1), "valid")
        walk = walk / max(np.abs(walk).max(), 1.0) * 0.25 * scale[j]
        bias[:, j] = off + A * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) + walk
    white = np.array([np.radians(0.03), np.radians(0.03), 5e-5, np.radians(0.15), np.radians(0.15),
                      np.radians(0.15), np.radians(0.3)])
    return q + bias + rng.normal(0, 1, q.shape) * white


def handeye_error(rng, b_range=(0.002, 0.005), w_range_deg=(1.0, 3.0)) -> np.ndarray:
    """Delta (4x4): translation |b| ~ U(b_range) m and rotation |w| ~ U(w_range_deg) deg,
    in uniformly random directions (defaults 2-5 mm, 1-3 deg)."""
    b = rng.normal(size=3)
    w = rng.normal(size=3)
    b *= rng.uniform(*b_range) / np.linalg.norm(b)
    w *= np.radians(rng.uniform(*w_range_deg)) / np.linalg.norm(w)
    return bw_to_matrix(np.concatenate([b, w]))


def lumped_error(robot, E_true: np.ndarray, q_true: np.ndarray, q_read: np.ndarray) -> np.ndarray:
    """True E_t (n, 4, 4) = camera_T_link4_true . base_T_link4(q~_t)^-1."""
    c4 = E_true @ link_transforms(robot, q_true)[:, 4]
    return c4 @ invert(link_transforms(robot, q_read)[:, 4])


def excursion(robot, camera, cam_T_base, q: np.ndarray, start: int, ramp: int, hold: int):
    """Pull the tool out of view and back: q plus a raised-cosine bump (``ramp`` frames
    up, ``hold`` frames at full offset, ``ramp`` down) from ``start`` of the joint offset
    d = (d1, 0, -r): first a pure retraction r (insertion joint 3, multiples of 5 mm up to
    the joint limit), else the full retraction plus a yaw swing d1 = +-0.1, +-0.2, ... 0.6
    rad (within the limits) -- the first d that puts the tip outside the image (or
    behind the camera) in every held frame.

    Returns (q', d (3,) [rad, rad, m]), or (q, None) when no such offset is found.
    """
    n = len(q)
    prof = np.zeros(n)
    k = np.arange(n) - start
    up = (k >= 0) & (k < ramp)
    prof[up] = 0.5 - 0.5 * np.cos(np.pi * (k[up] + 1) / ramp)
    prof[(k >= ramp) & (k < ramp + hold)] = 1.0
    down = (k >= ramp + hold) & (k < 2 * ramp + hold)
    prof[down] = 0.5 + 0.5 * np.cos(np.pi * (k[down] - ramp - hold + 1) / ramp)
    held = np.nonzero(prof == 1.0)[0]
    if len(held) == 0:
        return q, None
    lim = robot.joint_limits
    room = float(np.min(q[held, 2])) - lim[2, 0]
    offsets = [(0.0, r) for r in np.arange(0.01, room + 1e-9, 0.005)]
    offsets += [(s * a, room) for a in np.arange(0.1, 0.61, 0.1) for s in (1, -1)]
    H, W = camera.height, camera.width
    for d1, r in offsets:
        qq = q[held].copy()
        qq[:, 0] += d1
        qq[:, 2] -= r
        if np.any(qq[:, 0] < lim[0, 0]) or np.any(qq[:, 0] > lim[0, 1]):
            continue
        L = cam_T_base @ link_transforms(robot, qq)
        tip = transform_points(L[:, robot.tool_tip.link], np.asarray(robot.tool_tip.position))
        uv = camera.project_raw(np.where(tip[:, 2:] > 1e-3, tip, [0, 0, 1.0]))
        inside = (tip[:, 2] > 1e-3) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        if not inside.any():
            out = q.copy()
            out[:, 0] += d1 * prof
            out[:, 2] -= r * prof
            return out, np.array([d1, 0.0, r])
    return q, None
