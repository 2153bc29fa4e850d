"""Occluders of randomized recordings: tissue folds and a second instrument over the shaft.

Coverage. The *visible shaft* at frame i is the part of the shaft's centre
line (link 4's z from -0.45 m to SHAFT_END, sampled every ~1 mm) that is in
front of the camera and imaged (its raw pixel inside the image, not folded back into
it by the distortion from outside the field of view); its *coverage* is the
fraction of those samples (i.e. of its 3-D length) hidden by an occluder: a
tissue mask > 1/4 at the sample's raw pixel, or an instrument hit nearer than
the shaft's front surface (centre-line depth - SHAFT_RADIUS) on its ray.

Planning (:func:`plan`). An occlusion covers a target fraction f of the
visible shaft at its middle frame m, then persists while the tool moves, so
the coverage measured per frame varies around f:

* tissue: a mask around the visible centre line's run [a, a + f] (a drawn in
  [0, 1 - f]; the drawn polyline is shortened by 0.7 w at each end, as its
  round ends reach past it), a polyline of half-width 2-4 shaft half-widths with a wobbly
  edge (fractal noise), textured as tissue of a random hue (light 0.3-1.1); its depth (for
  the right view) is 0.8 x the shaft's depth at the middle of the run.
  It unfolds and folds (scaled about its centroid 0.3 -> 1) over 6 frames.
* instrument: a second instrument shaft (radius SHAFT_RADIUS, dark metal)
  between camera and tool: the run [0, f] from the shaft's entry side is
  pulled towards the camera by lambda in [0.5, 0.75] (so it projects onto
  the same pixels, 1 / lambda times wider) and continued 0.2 m beyond the
  entry side, out of view. It slides in and out along its axis over 6 frames.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from graphtrack.robot.psm import SHAFT_END, SHAFT_RADIUS
from graphtrack.sim import textures
from graphtrack.sim.render import Material, Primitive, intersect

RAMP = 6
SHAFT_Z = np.linspace(-0.45, SHAFT_END, 460)
INSTRUMENT = Material((48.0, 48.0, 52.0), 0.35, 0.9, 140.0, 40.0)


@dataclass
class Occlusion:
    """One planned occluder over frames [start, end); coverage: measured per frame."""

    kind: str
    start: int
    end: int
    target: float
    depth: float
    mask: np.ndarray | None = None         # tissue: (H, W) float32 0..1 at full extent
    texture: np.ndarray | None = None      # tissue: (H, W, 3) uint8
    segment: tuple | None = None           # instrument: (p, q) camera frame, q the covered end
    coverage: list = field(default_factory=list)

    def ramp(self, i: int) -> float:
        return min(i - self.start + 1, self.end - i, RAMP) / RAMP

    def tissue_mask(self, i: int) -> np.ndarray:
        """(H, W) float32 mask of the fold at frame i (scaled about its centroid by the ramp)."""
        k = 0.3 + 0.7 * self.ramp(i)
        if k >= 1.0:
            return self.mask
        vs, us = np.nonzero(self.mask > 0.5)
        c = (float(us.mean()), float(vs.mean())) if len(us) else (0.0, 0.0)
        A = cv2.getRotationMatrix2D(c, 0.0, k)
        return cv2.warpAffine(self.mask, A, (self.mask.shape[1], self.mask.shape[0]))

    def primitives(self, i: int, to_view: np.ndarray | None = None) -> list[Primitive]:
        """The instrument at frame i in the view's frame (slides along its axis)."""
        p, q = self.segment
        a = (q - p) / np.linalg.norm(q - p)
        shift = (1.0 - self.ramp(i)) * (np.linalg.norm(q - p) * 0.5)
        p, q = p - shift * a, q - shift * a
        if to_view is not None:
            p, q = to_view[:3, :3] @ p + to_view[:3, 3], to_view[:3, :3] @ q + to_view[:3, 3]
            a = to_view[:3, :3] @ a
        L = float(np.linalg.norm(q - p))
        return [Primitive("cyl", p, a, SHAFT_RADIUS, 0.0, L, "instrument"),
                Primitive("cap", q, a, 0.6 * SHAFT_RADIUS, 0.0, 0.008, "instrument")]


def shaft_samples(L4: np.ndarray, camera) -> tuple[np.ndarray, np.ndarray]:
    """Visible centre-line samples of the shaft: (points (M, 3) camera frame, raw uv (M, 2));
    a sample is visible when it is 1 cm or more in front of the camera and imaged
    (:meth:`graphtrack.geometry.camera.Camera.in_image`: not a point far outside the field
    of view whose raw pixel the distortion folds back into the image)."""
    P = L4[:3, 3][None] + SHAFT_Z[:, None] * L4[:3, 2][None]
    P = P[(P[:, 2] > 0.01) & camera.in_image(P)]
    return P, (camera.project_raw(P) if len(P) else np.zeros((0, 2)))


def coverage(occ: Occlusion, i: int, L4: np.ndarray, camera) -> float:
    """Fraction of the visible shaft hidden by ``occ`` at frame i (module doc); NaN if none visible."""
    P, uv = shaft_samples(L4, camera)
    if len(P) == 0:
        return float("nan")
    if occ.kind == "tissue":
        m = occ.tissue_mask(i)
        iu, iv = np.round(uv).astype(int).T
        hidden = m[iv, iu] > 0.25
    else:
        x, y = P[:, 0] / P[:, 2], P[:, 1] / P[:, 2]
        t = np.full(len(P), np.inf)
        for pr in occ.primitives(i):
            t = np.minimum(t, intersect(pr, x, y)[0])
        hidden = t < P[:, 2] - SHAFT_RADIUS
    return float(np.mean(hidden))


def _tissue(rng, occ: Occlusion, P: np.ndarray, uv: np.ndarray, camera, a: float) -> None:
    H, W = camera.height, camera.width
    n = len(P)
    lo, hi = int(a * n), max(int(a * n) + 2, int(round((a + occ.target) * n)))
    run = uv[lo:min(hi, n)]
    half = SHAFT_RADIUS * camera.fx / float(np.median(P[:, 2]))
    w = half * rng.uniform(2.0, 4.0)
    s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(run, axis=0).T))]   # the fold's round ends
    if s[-1] > 2.5 * w:                                             # reach w past the run
        run = run[(s >= 0.7 * w) & (s <= s[-1] - 0.7 * w)]
    m = np.zeros((H, W), np.float32)
    cv2.polylines(m, [np.round(run * 4).astype(np.int32)], False, 1.0, max(1, int(round(2 * w))), cv2.LINE_AA,
                  shift=2)
    for end in (run[0], run[-1]):
        cv2.circle(m, (int(round(end[0])), int(round(end[1]))), int(round(w)), 1.0, -1, cv2.LINE_AA)
    wob = textures.fractal_noise(rng, H, W, base=max(2, int(w)), octaves=3)
    m = cv2.GaussianBlur(m, (0, 0), max(1.0, 0.4 * w))
    occ.mask = np.clip((m - 0.5 + 0.35 * wob) * 6.0 + 0.5, 0, 1).astype(np.float32)
    base = rng.uniform([40, 40, 120], [160, 160, 240])
    occ.texture = textures.tissue(rng, H, W, tuple(base), rng.uniform(0.3, 1.1))
    occ.depth = 0.8 * float(P[min((lo + hi) // 2, n - 1), 2])


def _instrument(rng, occ: Occlusion, P: np.ndarray) -> None:
    n = len(P)
    hi = max(2, int(round(occ.target * n)))
    A, B = P[0], P[min(hi, n) - 1]
    lam = rng.uniform(0.5, 0.75)
    q = lam * B
    d = (lam * A - q) / np.linalg.norm(lam * A - q)
    occ.segment = (q + 0.2 * d, q)   # p far out beyond the entry side, q the covered end
    occ.depth = float(lam * np.mean(P[:hi, 2]))


def plan(rng, windows: list[tuple[int, int, float]], L_true: np.ndarray, camera) -> list[Occlusion]:
    """One occluder per (start, end, target coverage) window (module doc)."""
    out = []
    for s, e, f in windows:
        m = (s + e) // 2
        P, uv = shaft_samples(L_true[m, 4], camera)
        if len(P) < 4:
            continue
        kind = "instrument" if rng.uniform() < 0.5 else "tissue"
        occ = Occlusion(kind, s, e, float(f), 0.0)
        if kind == "tissue":
            _tissue(rng, occ, P, uv, camera, rng.uniform(0.0, 1.0 - f))
        else:
            _instrument(rng, occ, P)
        occ.coverage = [coverage(occ, i, L_true[i, 4], camera) for i in range(s, e)]
        out.append(occ)
    return out
