"""Procedural backgrounds: white bench, tissue (noise + vessels + glints), random ones.

Everything is generated once per recording from a numpy Generator, so a seed
gives byte-identical images. Noise: value noise, i.e. uniform random grids of
size (H / s, W / s) upsampled bicubically, summed over octaves s = 2^k with
weights 0.5^k (fractal noise, zero mean, roughly unit range).
"""
from __future__ import annotations

import cv2
import numpy as np


def fractal_noise(rng, H: int, W: int, base: int = 128, octaves: int = 5) -> np.ndarray:
    """(H, W) float32 multi-octave value noise in about [-1, 1]."""
    out = np.zeros((H, W), np.float32)
    total = 0.0
    cell, amp = float(base), 1.0
    for _ in range(octaves):
        gh, gw = max(2, int(np.ceil(H / cell)) + 1), max(2, int(np.ceil(W / cell)) + 1)
        g = rng.uniform(-1, 1, (gh, gw)).astype(np.float32)
        out += amp * cv2.resize(g, (W, H), interpolation=cv2.INTER_CUBIC)
        total += amp
        cell, amp = cell / 2, amp * 0.5
    return out / total


def vignette(H: int, W: int, strength: float) -> np.ndarray:
    """(H, W) float32 gain 1 - strength r^2 (r = 1 at the image corner)."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float32)
    r2 = ((u - (W - 1) / 2) ** 2 + (v - (H - 1) / 2) ** 2) / (((W - 1) / 2) ** 2 + ((H - 1) / 2) ** 2)
    return (1.0 - strength * r2).astype(np.float32)


def white_bench(rng, H: int, W: int, level: float = 236.0) -> np.ndarray:
    """Bright, evenly lit white background with a faint gradient (uint8 BGR)."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float32)
    g = level + 6.0 * (u / W - 0.5) - 4.0 * (v / H - 0.5)
    img = np.stack([g + 2.0, g, g - 1.0], -1)
    return np.clip(img, 0, 255).astype(np.uint8)


def _vessels(rng, H: int, W: int, n: int) -> np.ndarray:
    """(H, W) float32 vessel map in [0, 1]: branching random walks, blurred."""
    m = np.zeros((H, W), np.float32)
    scale = max(H, W) / 960.0
    for _ in range(n):
        p = np.array([rng.uniform(0, W), rng.uniform(0, H)])
        ang = rng.uniform(0, 2 * np.pi)
        width = rng.uniform(1.0, 4.0) * scale
        for _ in range(int(rng.integers(1, 4))):   # a vessel and its branches
            pts = [p.copy()]
            a = ang
            for _ in range(int(rng.integers(15, 40))):
                a += rng.normal(0, 0.35)
                pts.append(pts[-1] + 12.0 * scale * np.array([np.cos(a), np.sin(a)]))
            cv2.polylines(m, [np.round(np.array(pts)).astype(np.int32)], False, 1.0,
                          max(1, int(round(width))), cv2.LINE_AA)
            p = pts[len(pts) // 2]
            ang = a + rng.choice([-1, 1]) * rng.uniform(0.5, 1.2)
            width *= 0.6
    return cv2.GaussianBlur(m, (0, 0), 1.2 * scale)


def tissue(rng, H: int, W: int, base_bgr=(95.0, 92.0, 190.0), light: float = 0.75,
           vig: np.ndarray | None = None) -> np.ndarray:
    """Pinkish-red tissue: fractal colour/brightness noise, vessels, glints (uint8 BGR)."""
    s = max(H, W) / 960.0
    n1 = fractal_noise(rng, H, W, base=int(160 * s) or 2)
    n2 = fractal_noise(rng, H, W, base=int(40 * s) or 2, octaves=3)
    base = np.asarray(base_bgr, np.float32)
    img = base[None, None] * (1.0 + 0.35 * n1[..., None] + 0.12 * n2[..., None])
    img[..., 1] *= 1.0 - 0.25 * np.clip(n1, 0, 1)                    # redder patches
    vs = _vessels(rng, H, W, int(rng.integers(6, 14)))
    dark = np.array([0.55, 0.45, 0.75], np.float32)
    img *= 1.0 - vs[..., None] * (1.0 - dark[None, None])
    # wet glints: small saturated highlights where the fine noise peaks
    g = fractal_noise(rng, H, W, base=int(12 * s) or 2, octaves=2)
    glint = np.clip((g - 0.7) * 8.0, 0, 1) * (n1 > 0.1)
    glint = cv2.GaussianBlur(glint.astype(np.float32), (0, 0), 1.0 * s)
    img = img * light + glint[..., None] * 170.0
    if vig is not None:
        img *= vig[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)


def random_background(rng, H: int, W: int, vig: np.ndarray | None = None) -> np.ndarray:
    """Domain-randomised background: tissue of a random hue (bright, or dark and low in
    contrast: light 0.2-0.45), flat colour, or noise blobs; each kind with probability 1/4."""
    kind = rng.integers(0, 4)
    if kind in (0, 3):
        base = rng.uniform([40, 40, 120], [160, 160, 240])
        light = rng.uniform(0.5, 1.1) if kind == 0 else rng.uniform(0.2, 0.45)
        return tissue(rng, H, W, tuple(base), light, vig)
    if kind == 1:
        c = rng.uniform(60, 250, 3)
        n = fractal_noise(rng, H, W, base=max(2, W // 4), octaves=3)
        img = c[None, None] * (1.0 + 0.1 * n[..., None])
    else:
        cols = rng.uniform(20, 250, (2, 3))
        n = fractal_noise(rng, H, W, base=max(2, W // 8), octaves=4)
        w = np.clip(n * 2 + 0.5, 0, 1)[..., None]
        img = cols[0][None, None] * w + cols[1][None, None] * (1 - w)
    if vig is not None:
        img = img * vig[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)


def noise_bank(rng, H: int, W: int, sigma: float, pad: int = 32):
    """Two uint8 arrays (positive, negative part) of Gaussian sensor noise, padded.

    Each frame adds a random (H, W) window of them: a cheap, seeded stand-in
    for fresh noise per frame.
    """
    n = np.round(rng.normal(0, sigma, (H + pad, W + pad, 3))).astype(np.int16)
    return np.clip(n, 0, 255).astype(np.uint8), np.clip(-n, 0, 255).astype(np.uint8)
