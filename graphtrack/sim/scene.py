"""The two simulated scenes, the tool's geometry, and per-frame compositing.

* ``structured``: white bench, bright even light (no fall-off), narrow field of
  view (fx = 1000 px at 960 px wide), mild barrel distortion, tool 8-12 cm away.
* ``tissue``: procedural tissue, low light with 1/d^2 fall-off from the
  endoscope tip, vignetting, sensor noise, wet glints, a tissue flap that
  occludes part of the shaft at times, wide field of view (fx = 620 px at 960),
  stronger barrel distortion, tool 12-18 cm away.
* ``randomize``: domain randomisation of the above (background kind and
  colours, shaft colour, light, blur, noise, distortion, intrinsics).

Tool geometry (each in its link's frame, metres; psm.py's numbers):
shaft = cylinder on link 4's z from -0.45 to SHAFT_END, radius SHAFT_RADIUS,
capped; wrist = capsule on link 4's z from SHAFT_END to 0 (r 3.7 mm) and
capsule from link 5's origin to link 6's origin (r 2.8 mm); jaws = capsules
along +y of links 7 and 8 from the origin to JAW_LENGTH - r (r 1.2 mm), so the
inferior jaw's extremity is the tool tip (link 7, (0, JAW_LENGTH, 0)).
Markers: robot.json's point features on link 4, painted discs (render.py).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from graphtrack.geometry.camera import Camera
from graphtrack.sim import textures
from graphtrack.sim.render import Material, Primitive, ToolRenderer
from graphtrack.robot.psm import JAW_LENGTH, SHAFT_END, SHAFT_RADIUS

SCENES = ("structured", "tissue")
JAW_R, WRIST_R, CLEVIS_R = 0.0012, 0.0037, 0.0028


def tool_primitives(L: np.ndarray) -> list[Primitive]:
    """Primitives in the camera frame from camera_T_link (n_links + 1, 4, 4)."""
    def o(k):
        return L[k, :3, 3]

    def ax(k, i):
        return L[k, :3, i]

    prims = [Primitive("cyl", o(4), ax(4, 2), SHAFT_RADIUS, -0.45, SHAFT_END, "shaft", shaft=True,
                       frame=(o(4), ax(4, 0), ax(4, 1), ax(4, 2))),
             Primitive("cap", o(4), ax(4, 2), WRIST_R, SHAFT_END, 0.0, "wrist")]
    d = o(6) - o(5)
    prims.append(Primitive("cap", o(5), d / np.linalg.norm(d), CLEVIS_R, 0.0, float(np.linalg.norm(d)), "wrist"))
    for k in (7, 8):
        prims.append(Primitive("cap", o(k), ax(k, 1), JAW_R, 0.0, JAW_LENGTH - JAW_R, "jaw"))
    return prims


@dataclass
class Scene:
    kind: str
    camera: Camera
    distance: float
    materials: dict
    light: float
    falloff: float
    vig: np.ndarray | None
    background: np.ndarray
    noise: tuple | None
    blur: float
    flap_tex: np.ndarray | None = None
    events: list = field(default_factory=list)
    renderer: ToolRenderer | None = None

    def setup_renderer(self, robot, antialias: bool = True) -> None:
        self.renderer = ToolRenderer(self.camera, self.materials, self.light, self.falloff,
                                     self.distance, self.vig, antialias)
        mk = [p for p in robot.point_features if p.link == 4 and p.radius > 0]
        self.renderer.markers = np.array([[np.arctan2(p.position[1], p.position[0]), p.position[2], p.radius]
                                          for p in mk]).reshape(-1, 3)

    def plan_occlusions(self, rng, L_true: np.ndarray) -> None:
        """Tissue flaps over the shaft: [(start, end, centre uv, radius, polygon offsets)].

        L_true: (N, n_links + 1, 4, 4) camera_T_link of the true poses.
        """
        self.events = []
        if self.flap_tex is None:
            return
        n = len(L_true)
        W = self.camera.width
        t = int(rng.integers(0, 60))
        while t < n - 10:
            dur = int(rng.integers(30, 90))
            z = rng.uniform(-0.06, -0.02)
            p = L_true[t, 4, :3, 3] + z * L_true[t, 4, :3, 2]
            c = self.camera.project_raw(p)
            c = c + rng.normal(0, 0.02 * W, 2)
            rad = rng.uniform(0.06, 0.11) * W
            shape = 1.0 + 0.25 * np.convolve(np.tile(rng.normal(0, 1, 24), 3), np.ones(3) / 3, "same")[24:48]
            self.events.append((t, min(n, t + dur), c, rad, shape))
            t += dur + int(rng.integers(60, 200))

    def flap_mask(self, i: int):
        """(mask over the bbox, (v0, v1, u0, u1)) of the flap at frame i, or None."""
        H, W = self.camera.height, self.camera.width
        for (s, e, c, rad, shape) in self.events:
            if s <= i < e:
                k = min(i - s, e - 1 - i, 10) / 10.0       # folds in and out over 10 frames
                r = rad * (0.3 + 0.7 * k) * shape
                a = np.linspace(0, 2 * np.pi, len(shape), endpoint=False)
                pts = c[None] + r[:, None] * np.stack([np.cos(a), 0.8 * np.sin(a)], -1)
                u0, v0 = np.maximum(np.floor(pts.min(0)).astype(int), 0)
                u1, v1 = np.minimum(np.ceil(pts.max(0)).astype(int) + 1, [W, H])
                if u0 >= u1 or v0 >= v1:
                    return None
                m = np.zeros((v1 - v0, u1 - u0), np.uint8)
                cv2.fillPoly(m, [np.round((pts - [u0, v0]) * 4).astype(np.int32)], 255, cv2.LINE_AA, shift=2)
                return m, (v0, v1, u0, u1)
        return None

    def compose(self, prims, i: int, rng, tip_uv=None):
        """Frame i: background, tool, flap, noise, blur.

        Returns (uint8 BGR image, (depth m, primitive) of the tool at tip_uv, tip under a flap).
        """
        img = self.background.copy()
        probes = [] if tip_uv is None else [tip_uv]
        img, (depth, pid) = self.renderer.render(prims, img, probes)
        covered = False
        fm = self.flap_mask(i)
        if fm is not None:
            m, (v0, v1, u0, u1) = fm
            a = (m.astype(np.float32) / 255.0)[..., None]
            roi = img[v0:v1, u0:u1]
            img[v0:v1, u0:u1] = (a * self.flap_tex[v0:v1, u0:u1] + (1 - a) * roi + 0.5).astype(np.uint8)
            if tip_uv is not None:
                iu, iv = int(round(tip_uv[0])) - u0, int(round(tip_uv[1])) - v0
                covered = 0 <= iv < m.shape[0] and 0 <= iu < m.shape[1] and m[iv, iu] > 64
        if self.blur > 0:
            img = cv2.GaussianBlur(img, (0, 0), self.blur)
        if self.noise is not None:
            pos, neg = self.noise
            H, W = img.shape[:2]
            dv, du = rng.integers(0, pos.shape[0] - H + 1), rng.integers(0, pos.shape[1] - W + 1)
            cv2.add(img, pos[dv:dv + H, du:du + W], dst=img)
            cv2.subtract(img, neg[dv:dv + H, du:du + W], dst=img)
        hit = (depth[0], prims[pid[0] - 1] if 0 < pid[0] <= len(prims) else None) if len(depth) else (np.inf, None)
        return img, hit, covered


def _materials(shaft_bgr=(38.0, 38.0, 42.0)) -> dict:
    return {"shaft": Material(shaft_bgr, 0.35, 0.9, 110.0, 30.0),
            "marker": Material((230.0, 130.0, 30.0), 0.3, 0.85, 20.0, 10.0),
            "wrist": Material((165.0, 168.0, 172.0), 0.25, 0.65, 255.0, 40.0),
            "jaw": Material((135.0, 138.0, 142.0), 0.25, 0.6, 220.0, 30.0)}


def make_scene(kind: str, size: tuple[int, int], rng, randomize: bool = False,
               noise_free: bool = False) -> Scene:
    """Camera, look and background of one recording (the camera pose is set later)."""
    H, W = size
    s = W / 960.0
    if kind == "structured":
        fx, dist, distance = 1000.0, [-0.12, 0.03, 0.0, 0.0, 0.0], rng.uniform(0.08, 0.12)
    else:
        fx, dist, distance = 620.0, [-0.28, 0.09, 0.0005, -0.0004, 0.0], rng.uniform(0.12, 0.18)
    fx *= s
    cx, cy = (W - 1) / 2.0 + rng.uniform(-0.01, 0.01) * W, (H - 1) / 2.0 + rng.uniform(-0.01, 0.01) * H
    mats = _materials()
    light, falloff, vig_s, sigma, blur = 1.0, 0.0, 0.0, 0.0, 0.0
    if kind == "tissue":
        light, falloff, vig_s, sigma = 0.8, 2.0, 0.45, 3.0
    if randomize:
        fx *= rng.uniform(0.6, 1.6)
        dist = [rng.uniform(-0.35, 0.0), rng.uniform(0.0, 0.12), rng.uniform(-1e-3, 1e-3),
                rng.uniform(-1e-3, 1e-3), 0.0]
        g = rng.uniform(10, 110)
        mats["shaft"] = Material(tuple(g + rng.uniform(-8, 8, 3)), rng.uniform(0.2, 0.5),
                                 rng.uniform(0.6, 1.0), rng.uniform(30, 200), rng.uniform(8, 60))
        light, falloff = rng.uniform(0.55, 1.3), rng.choice([0.0, 1.0, 2.0])
        vig_s, sigma, blur = rng.uniform(0, 0.6), rng.uniform(0, 8), rng.choice([0.0, rng.uniform(0.3, 1.5)])
    if noise_free:
        sigma, blur = 0.0, 0.0
    K = np.array([[fx, 0, cx], [0, fx, cy], [0, 0, 1.0]])
    cam = Camera(K, np.array(dist, float), H, W)
    vig = textures.vignette(H, W, vig_s) if vig_s > 0 else None
    flap = None
    if randomize:
        bg = textures.random_background(rng, H, W, vig)
        if rng.uniform() < 0.5 and not noise_free:
            flap = textures.random_background(rng, H, W)
    elif kind == "structured":
        bg = textures.white_bench(rng, H, W)
    else:
        bg = textures.tissue(rng, H, W, light=light, vig=vig)
        if not noise_free:
            flap = textures.tissue(rng, H, W, base_bgr=(110.0, 105.0, 205.0), light=light)
    noise = textures.noise_bank(rng, H, W, sigma) if sigma > 0 else None
    return Scene(kind, cam, float(distance), mats, float(light), float(falloff), vig, bg, noise,
                 float(blur), flap)
