"""Training frames for the learned detector from the simulator.

``generate(frames, seed)`` draws ``ceil(frames / per_recording)`` short
simulated recordings (:class:`graphtrack.sim.simulate.Simulation`, the
in-memory form of :func:`graphtrack.sim.simulate`), alternating the two
scenes (structured, tissue); 3 in 4 are domain-randomised (``randomize=True``:
background kind and colours, shaft colour and gloss, light and fall-off,
vignetting, blur, noise, distortion, intrinsics, flaps), 1 in 4 use the plain
scene look. Recording k uses seed ``TRAIN_SEED_BASE + 1000 * seed + k``
(far from the small seeds of tests and benchmarks). From each recording's
``SPAN``-frame trajectory ``per_recording`` frames spread evenly over it are
rendered at ``render_size`` (default 270x480, half the camera's 540x960: 4x
cheaper, and the same 135x240 network input after resizing).

Per rendered frame: the raw image is undistorted with the recording's camera
(same K), resized to ``scale`` of the FULL 540x960 geometry (135x240,
cv2.INTER_AREA), and labelled with the visible shaft edge segments
(:func:`graphtrack.training.labels.shaft_edge_segments` with truth E_t
and the joint READINGS q~_t), minus the parts under a tissue flap (sampled
every reduced px, mapped to raw pixels, dropped where the flap mask > 1/4).
Returns images (N, h, w, 3) uint8 BGR and segments (N, MAX_SEG, 4) float32 in
reduced px (NaN rows for absent ones).
"""
from __future__ import annotations

import math
import time

import cv2
import numpy as np

from graphtrack.errors import InputError
from graphtrack.sim.scene import SCENES
from graphtrack.sim.simulate import Simulation
from graphtrack.training.labels import shaft_edge_segments, to_reduced

TRAIN_SEED_BASE = 100_000
SPAN = 150            #: frames of each recording's trajectory (5 s)
MAX_SEG = 6           #: segments per frame (2 edges, each split at most twice by a flap)


def visible_runs(seg: np.ndarray, camera, flap, step: float) -> list[np.ndarray]:
    """The parts (x1, y1, x2, y2) of an undistorted segment (camera px) not under the
    occluder mask ``flap`` (``Scene.flap_mask``: raw px, hidden where > 64), sampled every ``step`` px."""
    if flap is None:
        return [seg]
    m, (v0, v1, u0, u1) = flap
    a, b = seg[:2], seg[2:]
    n = max(2, int(math.ceil(np.hypot(*(b - a)) / step)) + 1)
    t = np.linspace(0.0, 1.0, n)
    pts = a[None] + t[:, None] * (b - a)[None]
    raw = camera.distort_pixels(pts)
    iu, iv = np.round(raw[:, 0]).astype(int) - u0, np.round(raw[:, 1]).astype(int) - v0
    inside = (iu >= 0) & (iu < m.shape[1]) & (iv >= 0) & (iv < m.shape[0])
    hidden = np.zeros(n, bool)
    hidden[inside] = m[iv[inside], iu[inside]] > 64
    runs, start = [], None
    for i in range(n + 1):
        vis = i < n and not hidden[i]
        if vis and start is None:
            start = i
        elif not vis and start is not None:
            if i - 1 > start:
                runs.append(np.r_[pts[start], pts[i - 1]])
            start = None
    return runs


def generate(frames: int, seed: int = 0, per_recording: int = 24, render_size=(270, 480),
             full_size=(540, 960), scale: float = 0.25, plain_every: int = 4, progress=None):
    """(images (N, h, w, 3) uint8, segments (N, MAX_SEG, 4) float32, info dict); see the module doc."""
    frames = int(frames)
    per = max(1, min(int(per_recording), frames))
    n_rec = int(math.ceil(frames / per))
    hs, ws = int(round(full_size[0] * scale)), int(round(full_size[1] * scale))
    images = np.zeros((frames, hs, ws, 3), np.uint8)
    segs = np.full((frames, MAX_SEG, 4), np.nan, np.float32)
    t0 = time.perf_counter()
    k = 0
    for r in range(n_rec):
        scene = SCENES[r % len(SCENES)]
        randomize = (r % plain_every) != plain_every - 1
        take = min(per, frames - k)
        sim = Simulation(scene, SPAN, TRAIN_SEED_BASE + 1000 * int(seed) + r, render_size, randomize=randomize)
        cam = sim.camera
        idx = np.linspace(0, SPAN - 1, take).round().astype(int)
        for i in idx:
            raw, _ = sim.render(int(i))
            und = cam.undistort(raw)
            images[k] = cv2.resize(und, (ws, hs), interpolation=cv2.INTER_AREA)
            full = shaft_edge_segments(sim.robot, sim.q_read[i], sim.E_t[i], cam.K, cam.height, cam.width)
            flap = sim.scene.flap_mask(int(i))
            runs = [run for s in full for run in visible_runs(s, cam, flap, 1.0 / scale * cam.width / full_size[1])]
            red = to_reduced(np.array(runs).reshape(-1, 4), ws / cam.width, hs / cam.height)
            red = red[np.hypot(red[:, 2] - red[:, 0], red[:, 3] - red[:, 1]) >= 2.0][:MAX_SEG]
            segs[k, :len(red)] = red
            k += 1
        if progress is not None:
            progress(k, frames, time.perf_counter() - t0)
    info = {"frames": frames, "recordings": n_rec, "per_recording": per, "render_size": list(render_size),
            "scale": scale, "seconds": round(time.perf_counter() - t0, 1)}
    return images, segs, info


def save_cache(path, images: np.ndarray, segments: np.ndarray) -> None:
    """Write generated frames to the ``.npz`` cache ``path`` (keys ``images``, ``segments``)."""
    try:
        with open(path, "wb") as f:
            np.savez(f, images=images, segments=segments)
    except OSError as e:
        raise InputError(f"{path}: cannot write the --data cache ({e.strerror or e})") from None


MIN_CACHE_SIZE = 16   #: px, the smallest image side of a training cache (the net downsamples by 4)


def load_cache(path) -> tuple[np.ndarray, np.ndarray]:
    """(images, segments) of a cache written by :func:`save_cache`; InputError naming the
    file when it is not such a cache: not an .npz, a key missing, or images that are not
    (N, h, w, 3) uint8 with segments (N, S, 4) beside them."""
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in ("images", "segments") if k not in z.files]
            if missing:
                raise InputError(f"{path}: not a training-data cache: no {' or '.join(repr(k) for k in missing)} array "
                                 "(write one with graphtrack train --data)")
            images, segments = z["images"], z["segments"]
    except InputError:
        raise
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from None
    except Exception as e:   # numpy raises ValueError / BadZipFile / EOFError for a file that is not an .npz
        raise InputError(f"{path}: not a readable .npz training-data cache ({type(e).__name__})") from None
    if (images.dtype != np.uint8 or images.ndim != 4 or images.shape[3] != 3 or len(images) == 0
            or min(images.shape[1:3]) < MIN_CACHE_SIZE):
        raise InputError(f"{path}: 'images' must be (N, h, w, 3) uint8 with N >= 1 and h, w >= {MIN_CACHE_SIZE}, "
                         f"got {images.shape} {images.dtype}")
    if (segments.dtype.kind not in "fiu" or segments.ndim != 3 or segments.shape[0] != len(images)
            or segments.shape[1] < 1 or segments.shape[2] != 4):
        raise InputError(f"{path}: 'segments' must be numbers (N, S, 4) with N = {len(images)} images and "
                         f"S >= 1, got {segments.shape} {segments.dtype}")
    return images, segments.astype(np.float32)
