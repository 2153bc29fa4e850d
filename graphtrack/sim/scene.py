"""The two simulated scenes, the tool's geometry, and per-frame compositing.

* ``structured``: white bench, bright even light (no fall-off), narrow field of
  view (fx = 1000 px at 960 px wide), mild barrel distortion, tool 8-12 cm away.
* ``tissue``: procedural tissue, low light with 1/d^2 fall-off from the
  endoscope tip, vignetting, sensor noise, wet glints, a tissue flap that
  occludes part of the shaft at times, wide field of view (fx = 620 px at 960),
  stronger barrel distortion, tool 12-18 cm away.
* ``randomize``: domain randomisation of the above (background kind and
  colours, shaft and second-instrument colour and gloss, light, blur, noise,
  distortion, intrinsics); the occluders (sim/occluders.py) and image
  effects (sim/effects.py) are drawn by the simulation
  (docs/randomized-recordings.md lists every range).

Views: the left camera, and for stereo a right one (:meth:`Scene.add_view`)
that ray-casts the same tool and sees the 2-D layers (background, flaps) as
planes at a depth (sim/stereo.py).

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
from graphtrack.robot.psm import JAW_LENGTH, SHAFT_END, SHAFT_RADIUS
from graphtrack.sim import stereo, textures
from graphtrack.sim.render import MARKER_ID, Material, Primitive, ToolRenderer, intersect

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
    vig_strength: float = 0.0
    event_depths: list = field(default_factory=list)
    occlusions: list = field(default_factory=list)    # randomized: sim.occluders.Occlusion
    effects: object = None                            # randomized: sim.effects.Effects
    views: list = field(default_factory=list)

    def setup_renderer(self, robot, antialias: bool = True) -> None:
        self.renderer = ToolRenderer(self.camera, self.materials, self.light, self.falloff,
                                     self.distance, self.vig, antialias)
        self.views = []
        mk = [p for p in robot.point_features if p.link == 4 and p.radius > 0]
        self.renderer.markers = np.array([[np.arctan2(p.position[1], p.position[0]), p.position[2], p.radius]
                                          for p in mk]).reshape(-1, 3)

    def plan_occlusions(self, rng, L_true: np.ndarray) -> None:
        """Tissue flaps over the shaft: [(start, end, centre uv, radius, polygon offsets)].

        L_true: (N, n_links + 1, 4, 4) camera_T_link of the true poses.
        """
        self.events, self.event_depths = [], []
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
            self.event_depths.append(0.8 * float(p[2]))      # in front of the shaft (right view)
            t += dur + int(rng.integers(60, 200))

    def flap_mask(self, i: int, legacy: bool = False):
        """(uint8 mask over its bbox, (v0, v1, u0, u1)) of what hides the shaft at frame i
        in the left view (the tissue scene's flap, a randomized fold or instrument), or None.
        ``legacy``: the tissue scene's flap only."""
        if not legacy and self.occlusions:
            return self._occluder_mask(i)
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

    def _occluder_mask(self, i: int):
        H, W = self.camera.height, self.camera.width
        m = np.zeros((H, W), np.float32)
        for o in self.occlusions:
            if not o.start <= i < o.end:
                continue
            if o.kind == "tissue":
                m = np.maximum(m, o.tissue_mask(i))
                continue
            X, Y = self.renderer.rays.x[1:-1, 1:-1], self.renderer.rays.y[1:-1, 1:-1]
            for pr in o.primitives(i):
                m = np.maximum(m, np.isfinite(intersect(pr, X, Y)[0]).astype(np.float32))
        vs, us = np.nonzero(m > 0)
        if len(vs) == 0:
            return None
        v0, v1, u0, u1 = vs.min(), vs.max() + 1, us.min(), us.max() + 1
        return (np.round(m[v0:v1, u0:u1] * 255).astype(np.uint8), (v0, v1, u0, u1))

    def add_view(self, camera: Camera, to_view: np.ndarray, rng, antialias: bool = True) -> "View":
        """A second camera (``to_view``: its 4x4 from the left camera, metres) of the same scene."""
        vig = textures.vignette(camera.height, camera.width, self.vig_strength) if self.vig is not None else None
        r = ToolRenderer(camera, self.materials, self.light, self.falloff, self.distance, vig, antialias)
        r.markers = self.renderer.markers
        R, T = to_view[:3, :3], to_view[:3, 3]
        left = self.camera
        view = View(camera, r, None, rng, to_view, lambda d: stereo.plane_map(left, camera, R, T, d))
        view.background = view.layer(self.background, self.distance * 1.3)
        self.views.append(view)
        return view

    def left_view(self, rng) -> "View":
        if not self.views:
            self.views.append(View(self.camera, self.renderer, self.background, rng, None, None))
        return self.views[0]

    def _legacy_flap(self, view: "View", img, i: int):
        """The tissue scene's flap at frame i over img; returns its mask over the view (or None)."""
        fm = self.flap_mask(i, legacy=True)
        if fm is None:
            return None
        m, (v0, v1, u0, u1) = fm
        if view.to_view is None:
            a = (m.astype(np.float32) / 255.0)[..., None]
            roi = img[v0:v1, u0:u1]
            img[v0:v1, u0:u1] = (a * self.flap_tex[v0:v1, u0:u1] + (1 - a) * roi + 0.5).astype(np.uint8)
            full = np.zeros(img.shape[:2], np.uint8)
            full[v0:v1, u0:u1] = m
            return full
        full = np.zeros(img.shape[:2], np.uint8)
        full[v0:v1, u0:u1] = m
        k = [e[0] for e in self.events].index(next(e[0] for e in self.events if e[0] <= i < e[1]))
        depth = self.event_depths[k]
        mv = view.layer(full, depth)
        _blend(img, mv.astype(np.float32) / 255.0, view.layer(self.flap_tex, depth))
        return mv

    def compose(self, view: "View", prims, i: int, tip_uv=None, velocity=None):
        """Frame i in ``view``: background, tool (+ instrument), flaps and folds, effects, noise.

        prims: the tool in the view's frame; tip_uv: raw pixel to probe; velocity:
        the tool tip's image motion (px / frame) for motion blur.
        Returns (uint8 BGR image, (depth m, primitive) of the tool at tip_uv, tip under a flap).
        """
        img = view.background.copy()
        probes = [] if tip_uv is None else [tip_uv]
        n_tool = len(prims)
        prims = list(prims) + [p for o in self.occlusions if o.kind == "instrument" and o.start <= i < o.end
                               for p in o.primitives(i, view.to_view)]
        img, (depth, pid) = view.renderer.render(prims, img, probes)
        masks = []
        if self.effects is not None and self.effects.exposure > 0:
            v, u, ids = view.renderer.drawn
            tool = np.zeros(img.shape[:2], np.uint8)
            keep = (ids <= n_tool) | (ids == MARKER_ID)
            tool[v[keep], u[keep]] = 1
            img = self.effects.motion_blur(img, tool, velocity)
        m = self._legacy_flap(view, img, i)
        if m is not None:
            masks.append((m, 64))
        for o in self.occlusions:
            if o.kind == "tissue" and o.start <= i < o.end:
                a = view.layer(o.tissue_mask(i), o.depth)
                _blend(img, a, view.layer(o.texture, o.depth))
                masks.append((a, 0.25))
        if self.effects is not None:
            img = self.effects.apply(img, i)
        covered = False
        if tip_uv is not None:
            iu, iv = int(round(tip_uv[0])), int(round(tip_uv[1]))
            H, W = img.shape[:2]
            covered = 0 <= iv < H and 0 <= iu < W and any(mk[iv, iu] > th for mk, th in masks)
        if self.blur > 0:
            img = cv2.GaussianBlur(img, (0, 0), self.blur)
        if self.noise is not None:
            pos, neg = self.noise
            H, W = img.shape[:2]
            dv, du = view.rng.integers(0, pos.shape[0] - H + 1), view.rng.integers(0, pos.shape[1] - W + 1)
            cv2.add(img, pos[dv:dv + H, du:du + W], dst=img)
            cv2.subtract(img, neg[dv:dv + H, du:du + W], dst=img)
        hit = (depth[0], prims[pid[0] - 1] if 0 < pid[0] <= len(prims) else None) if len(depth) else (np.inf, None)
        return img, hit, covered


@dataclass
class View:
    """One camera of the scene: its renderer, its background, its noise stream; to_view:
    4x4 view_T_left (None for the left camera); plane_map(depth): remap tables that show
    a left-view 2-D layer at that depth in this view (see sim/stereo.py)."""

    camera: Camera
    renderer: ToolRenderer
    background: np.ndarray | None
    rng: object
    to_view: np.ndarray | None
    plane_map: object
    _maps: dict = field(default_factory=dict)

    def layer(self, img: np.ndarray, depth: float) -> np.ndarray:
        if self.to_view is None:
            return img
        key = round(float(depth), 4)
        if key not in self._maps:
            self._maps[key] = self.plane_map(key)
        return stereo.warp(img, self._maps[key])


def _blend(img: np.ndarray, alpha: np.ndarray, tex: np.ndarray) -> None:
    """img = alpha tex + (1 - alpha) img over alpha's bounding box (in place)."""
    vs, us = np.nonzero(alpha > 1e-3)
    if len(vs) == 0:
        return
    v0, v1, u0, u1 = vs.min(), vs.max() + 1, us.min(), us.max() + 1
    a = alpha[v0:v1, u0:u1, None]
    img[v0:v1, u0:u1] = (a * tex[v0:v1, u0:u1] + (1 - a) * img[v0:v1, u0:u1] + 0.5).astype(np.uint8)


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
                                 rng.uniform(0.6, 1.0), rng.uniform(30, 255), rng.uniform(8, 150))
        gi = rng.uniform(25, 90)
        mats["instrument"] = Material(tuple(gi + rng.uniform(-6, 6, 3)), rng.uniform(0.2, 0.5),
                                      rng.uniform(0.6, 1.0), rng.uniform(30, 255), rng.uniform(8, 150))
        light, falloff = rng.uniform(0.55, 1.3), rng.choice([0.0, 1.0, 2.0])
        vig_s, sigma, blur = rng.uniform(0, 0.7), rng.uniform(0, 8), rng.choice([0.0, rng.uniform(0.3, 1.5)])
    if noise_free:
        sigma, blur = 0.0, 0.0
    K = np.array([[fx, 0, cx], [0, fx, cy], [0, 0, 1.0]])
    cam = Camera(K, np.array(dist, float), H, W)
    vig = textures.vignette(H, W, vig_s) if vig_s > 0 else None
    flap = None
    if randomize:
        bg = textures.random_background(rng, H, W, vig)
    elif kind == "structured":
        bg = textures.white_bench(rng, H, W)
    else:
        bg = textures.tissue(rng, H, W, light=light, vig=vig)
        if not noise_free:
            flap = textures.tissue(rng, H, W, base_bgr=(110.0, 105.0, 205.0), light=light)
    noise = textures.noise_bank(rng, H, W, sigma) if sigma > 0 else None
    return Scene(kind, cam, float(distance), mats, float(light), float(falloff), vig, bg, noise,
                 float(blur), flap, vig_strength=float(vig_s))
