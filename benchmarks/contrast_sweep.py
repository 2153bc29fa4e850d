"""The detection benchmark's contrast sweep (bench_detect.py): dark frames made from clear ones.

Real endoscope frames show a dark shaft on dark tissue, where the step at the shaft's
edge is a few gray levels. Every clear held-out frame is run again, made darker in two
ways with noise added (the sensor's noise does not shrink with the scene's light), per
channel, in gray levels:

    contrast (haze, flat light):  I_c = clip(round(m + c (I - m) + n))   (m: the frame's mean)
    light (a dim scene):          I_c = clip(round(c I + n))
                                  n ~ N(0, SWEEP_NOISE^2),  c in CONTRAST_SCALES

independent of how a renderer darkens a scene. Each scaled frame's contrast is
measured at the true edges (:func:`edge_contrast`), so a table row says at what
edge contrast (gray levels) a detector still finds both edges.
"""
from __future__ import annotations

import numpy as np

CONTRAST_SCALES = (0.5, 0.25, 0.125)   #: the sweep's scales (c = 1: the clear frames themselves)
SWEEP_NOISE = 2.0                      #: gray levels of noise added to a contrast-scaled frame
#: (mode, c) of every frame the sweep runs: the frame itself, then each scale both ways
SWEEP = (("clear", 1.0),) + tuple((m, c) for m in ("contrast", "light") for c in CONTRAST_SCALES)


def edge_contrast(sim, i: int, raw: np.ndarray, offset: float = 3.0, samples: int = 24) -> float:
    """The shaft's contrast with its background in the raw frame i (gray levels): per
    true edge segment, the median over ``samples`` points along its middle 80 % of
    |gray ``offset`` px to one side - gray ``offset`` px to the other| (read through the
    lens distortion, :func:`graphtrack.detect.shaft_end.raw_sampler`); the lower of the two
    edges. NaN without two edges in view."""
    from graphtrack.detect.shaft_end import raw_sampler
    from graphtrack.training.labels import shaft_edge_segments

    cam = sim.camera
    segs = shaft_edge_segments(sim.robot, sim.q_read[i], sim.E_t[i], cam.K, cam.height, cam.width)
    if len(segs) != 2:
        return float("nan")
    sample = raw_sampler(raw, cam)
    t = np.linspace(0.1, 0.9, samples)[:, None]
    out = []
    for a, b in zip(segs[:, :2], segs[:, 2:]):
        d = (b - a) / np.linalg.norm(b - a)
        n = np.array([-d[1], d[0]])
        p = a + t * (b - a)
        out.append(float(np.nanmedian(np.abs(sample(p - offset * n) - sample(p + offset * n)))))
    return min(out)


def scale_contrast(raw: np.ndarray, c: float, rng, about_mean: bool = True) -> np.ndarray:
    """``raw`` (uint8) with its intensities' spread about the frame's mean (``about_mean``;
    else about 0: dimmed) scaled by c, plus N(0, SWEEP_NOISE^2) gray levels of noise,
    clipped to uint8 (module doc)."""
    f = raw.astype(np.float32)
    m = float(f.mean()) if about_mean else 0.0
    out = m + (f - m) * c + rng.normal(0.0, SWEEP_NOISE, f.shape)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def sweep_frame(dets: dict, acc: dict, sim, i: int, raw: np.ndarray, rho, th, seed: int, errors, both,
                free: dict) -> None:
    """The sweep of one clear frame (module doc), free mode, into ``acc`` {(detector, mode, c): counts}:
    ``errors(lines, rho, th)`` and ``both(errors)`` judge the detections against the true limb
    lines (rho, th) as bench_detect.py does; ``free`` {detector: Detection}: each detector's
    free-mode detection on ``raw`` itself, already made (the c = 1 row)."""
    from graphtrack.detect import detect_raw

    for mode, c in SWEEP:
        img = raw if c == 1.0 else scale_contrast(raw, c, np.random.default_rng([seed, i, int(c * 1000)]),
                                                  about_mean=mode == "contrast")
        contrast = edge_contrast(sim, i, img)
        for name, det in dets.items():
            a = acc.setdefault((name, mode, c), {"both": 0, "err": [], "ms": [], "n": 0, "contrast": []})
            d = free[name] if c == 1.0 else detect_raw(det, img, sim.camera, None)
            e = errors(d.shaft_lines, rho, th)
            a["n"] += 1
            a["ms"].append(d.ms)
            a["err"] += e
            a["both"] += int(both(e))
            a["contrast"].append(contrast)


def contrast_table(rnd: dict) -> str:
    """Markdown: the sweep, free mode, a row per (mode, c): the median edge contrast and each
    detector's both-edges rate / median |d_rho| px."""
    names = [n for n in rnd if isinstance(rnd[n], dict) and rnd[n].get("contrast")]
    if not names:
        return ""

    def cell(f):
        return f"{f['both']:.3f} / {'-' if f['rho_px'] is None else f['rho_px']}"
    rows = ["| frames | edge contrast (gray levels) | " + " | ".join(names) + " |", "|" + "---|" * (len(names) + 2)]
    for i, f in enumerate(rnd[names[0]]["contrast"]):
        rows.append(f"| {f['mode']} x{f['c']} | {f['edge_contrast']} | "
                    + " | ".join(cell(rnd[n]["contrast"][i]) for n in names) + " |")
    return "\n".join(rows)
