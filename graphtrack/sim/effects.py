"""Image-space effects of randomized recordings: motion blur, lighting, smoke and haze.

Each is drawn once per recording (:func:`draw_effects`) and then applied per
frame without further random draws, so the left and right views of a stereo
recording get the same effect at the same frame. Applied in this order
(:meth:`Effects.apply`), after the tool is drawn and before sensor noise:

* motion blur (tool only): a line kernel along the tool tip's image velocity
  v (px / frame) of length |v| * exposure (exposure = open-shutter fraction
  of the frame time); the blurred frame replaces the original where the
  blurred tool mask is > 0, weighted by that mask (the static background
  stays sharp away from the tool). Skipped below 1.5 px.
* lighting: a global gain g_i = 1 + a sin(2 pi f t_i + phi) times an
  auto-exposure step: from frame k on the gain moves to (1 + s) over 6
  frames (exponential approach).
* smoke: alpha_i(u, v) = density_i * clip(0.3 + N(u + dx_i, v + dy_i), 0, 1)
  with N fractal noise in [-1, 1] drifting at (dx, dy) px per frame and
  density_i a raised-cosine puff over [start, end) (rise 1/3, decay 2/3);
  the pixel becomes (1 - alpha) I + alpha * colour.
* haze: a constant veil, (1 - h) I + h * colour (scattering in the cavity).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from graphtrack.sim import textures

FPS = 30.0


@dataclass
class Effects:
    """Per-recording effect parameters (see module doc); ``info`` is what scenario.json records."""

    n: int
    exposure: float = 0.0
    gain: np.ndarray | None = None
    smoke_tex: np.ndarray | None = None
    smoke_density: np.ndarray | None = None
    smoke_drift: tuple = (0.0, 0.0)
    smoke_colour: np.ndarray = field(default_factory=lambda: np.array([200.0, 200.0, 205.0]))
    haze: float = 0.0
    haze_colour: np.ndarray = field(default_factory=lambda: np.array([210.0, 210.0, 215.0]))
    info: dict = field(default_factory=dict)

    def motion_blur(self, img, mask, velocity) -> np.ndarray:
        """Blur the tool (mask, uint8 0/1) along ``velocity`` (px / frame) for ``exposure``."""
        if mask is None or velocity is None or not np.all(np.isfinite(velocity)):
            return img
        L = float(np.hypot(*velocity)) * self.exposure
        if L < 1.5 or not mask.any():
            return img
        n = int(np.ceil(L)) | 1
        k = np.zeros((n, n), np.float32)
        c = (n - 1) / 2.0
        d = np.asarray(velocity, float) / np.hypot(*velocity)
        for s in np.linspace(-L / 2, L / 2, 2 * n):
            k[int(round(c + s * d[1])), int(round(c + s * d[0]))] += 1.0
        k /= k.sum()
        vs, us = np.nonzero(mask)
        H, W = mask.shape
        v0, v1 = max(0, vs.min() - n), min(H, vs.max() + n + 1)
        u0, u1 = max(0, us.min() - n), min(W, us.max() + n + 1)
        roi = img[v0:v1, u0:u1].astype(np.float32)
        m = cv2.filter2D(mask[v0:v1, u0:u1].astype(np.float32), -1, k)[..., None]
        b = cv2.filter2D(roi, -1, k)
        img[v0:v1, u0:u1] = np.clip(m * b + (1 - m) * roi + 0.5, 0, 255).astype(np.uint8)
        return img

    def apply(self, img: np.ndarray, i: int) -> np.ndarray:
        """Lighting, smoke, haze on frame i (uint8 BGR, returned)."""
        H, W = img.shape[:2]
        f = img.astype(np.float32)
        if self.gain is not None:
            f *= np.float32(self.gain[i])
        if self.smoke_tex is not None and self.smoke_density[i] > 1e-3:
            dx = int(round(self.smoke_drift[0] * i)) % (self.smoke_tex.shape[1] - W)
            dy = int(round(self.smoke_drift[1] * i)) % (self.smoke_tex.shape[0] - H)
            a = np.clip(0.3 + self.smoke_tex[dy:dy + H, dx:dx + W], 0, 1) * np.float32(self.smoke_density[i])
            f = f * (1 - a[..., None]) + a[..., None] * self.smoke_colour.astype(np.float32)
        if self.haze > 0:
            f = f * np.float32(1 - self.haze) + np.float32(self.haze) * self.haze_colour.astype(np.float32)
        return np.clip(f + 0.5, 0, 255).astype(np.uint8)


def _gain(rng, n: int) -> tuple[np.ndarray, dict]:
    a, f, ph = rng.uniform(0.0, 0.25), rng.uniform(0.05, 0.5), rng.uniform(0, 2 * np.pi)
    t = np.arange(n) / FPS
    g = 1.0 + a * np.sin(2 * np.pi * f * t + ph)
    info = {"amplitude": a, "frequency_hz": f}
    if rng.uniform() < 0.4:
        k, s = int(rng.integers(0, n)), float(rng.choice([-1, 1]) * rng.uniform(0.1, 0.35))
        step = np.where(np.arange(n) >= k, s * (1 - np.exp(-(np.arange(n) - k + 1) / 6.0)), 0.0)
        g = g * (1.0 + step)
        info.update(step_frame=k, step=s)
    return g, info


def draw_effects(rng, n: int, H: int, W: int) -> Effects:
    """Draw one recording's effects (ranges: docs/randomized-recordings.md)."""
    e = Effects(n)
    info: dict = {}
    on = rng.uniform() < 0.6
    e.exposure = float(rng.uniform(0.3, 1.0)) if on else 0.0
    info["motion_blur"] = {"on": on, "exposure": e.exposure}
    on = rng.uniform() < 0.6
    g, gi = _gain(rng, n)
    e.gain = g if on else None
    info["lighting"] = {"on": on, **(gi if on else {})}
    on = rng.uniform() < 0.4
    if on:
        pad = int(0.25 * W)
        e.smoke_tex = textures.fractal_noise(rng, H + pad, W + pad, base=max(2, W // 5), octaves=4) * 1.6
        dur = int(rng.integers(int(1.0 * FPS), max(int(1.0 * FPS) + 1, min(n, int(4.0 * FPS)))))
        s = int(rng.integers(0, max(1, n - dur // 2)))
        peak = float(rng.uniform(0.25, 0.7))
        x = (np.arange(n) - s) / max(dur, 1)
        rise = np.clip(x / (1 / 3), 0, 1)
        decay = np.clip((1 - x) / (2 / 3), 0, 1)
        e.smoke_density = peak * np.where(x < 1 / 3, 0.5 - 0.5 * np.cos(np.pi * rise),
                                          0.5 - 0.5 * np.cos(np.pi * decay)) * ((x >= 0) & (x < 1))
        e.smoke_drift = tuple(rng.uniform(-1.5, 1.5, 2) * W / 960.0)
        info["smoke"] = {"on": True, "start": s, "end": min(n, s + dur), "peak_density": peak,
                         "drift_px_per_frame": [float(v) for v in e.smoke_drift]}
    else:
        info["smoke"] = {"on": False}
    on = rng.uniform() < 0.4
    e.haze = float(rng.uniform(0.05, 0.3)) if on else 0.0
    info["haze"] = {"on": on, "strength": e.haze}
    e.info = info
    return e
