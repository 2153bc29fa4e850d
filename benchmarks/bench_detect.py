"""Shaft-edge detectors on simulated recordings they were not trained on.

    python benchmarks/bench_detect.py [--frames 200] [--sold2 CKPT]   # prints the figures
    run(results)                                                      # fills results["detect"]

For each scene (structured, tissue) one plain (not randomised) recording of
FRAMES frames at 540x960 is simulated with seed SEEDS[scene] (the learned
detector's training recordings use seeds >= 100000 and are randomised 3 in 4);
each raw frame is given to every detector (canny, learned, and sold2 when a
checkpoint is given) as tracking gives it (``detect_raw``: undistorted for
canny and sold2, raw with its camera for the learned one), twice:

- free: no prediction (the association's pair search);
- gated: with a prediction = the true limb lines, perturbed by N(0, 5 px) in
  offset and N(0, 0.03 rad) in angle (what the tracker passes).

Truth: the limb lines shaft_lines(base_features(robot, q~).transformed(E_t), K)
(undistorted px). Figures per detector, scene and mode: ``both`` = fraction of
frames with both shaft edges found, each within 10 px and 0.05 rad of a true
limb line (wrong lines do not count); ``rho_px`` / ``theta_rad`` = median
|d_rho| / |d_theta| of the detected edges against their nearest true line;
``ms`` = median detection time per frame, one thread (torch, OpenCV);
``rho_p90`` = 90th percentile of |d_rho|. Each true line counts once: two
detected lines near the same limb are not both edges. What the pixel models
consume: ``set_px`` = median over the frames' ``line-intensities`` pixel sets of
|the set's median signed distance to its nearest true limb|, ``set_in_px`` the
median of that signed distance (+ inwards, into the shaft's image), and
``set_px_heatmap`` / ``set_in_px_heatmap`` the same for the sets as the heatmap
gives them, before refined edges' sets are carried onto their segments
(docs/decisions/pixel-sets-follow-refinement.md).

Randomized held-out set (``results["detect"]["randomized"]``): RECORDINGS
recordings per scene at 540x960, ``randomize=True``, each RAND_FRAMES frames
spread evenly over a RAND_SPAN-frame (5 s) recording
(occluders, out-of-view excursions, smoke/haze, motion blur, lighting, dark
low-contrast backgrounds), seeds HELD_OUT + k, k < RECORDINGS. These seeds
(800000-800099) are HELD OUT: nothing is trained (training uses
100000 + 1000 seed + r, r < 1000) or tuned on them. Per frame the truth says
how much of each shaft edge is visible: the true edge segment inside the
image (training.labels.shaft_edge_segments) minus what the occluder mask
covers (Scene.flap_mask). Frames are

- ``clear``: both edges at least MIN_VISIBLE px visible, nothing hidden;
- ``occluded``: both edges at least MIN_VISIBLE px visible, part hidden;
- ``absent``: under ABSENT px of edge visible in all (fully occluded or out
  of view): ``false`` = fraction of them where the detector reports any shaft
  line (free; gated with the true lines, when they exist, as prediction);
- the rest (one edge short or missing) are only counted (``marginal``).

Contrast sweep (``results["detect"]["randomized"][detector]["contrast"]``): every
clear frame again, free mode, with its contrast scaled down about its mean and dimmed
(:mod:`contrast_sweep`): a dark shaft on dark tissue, however a renderer makes one.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # runnable from a checkout
sys.path.insert(0, str(Path(__file__).resolve().parent))      # its helper modules

from contrast_sweep import contrast_table, sweep_frame  # noqa: E402

FRAMES = 200
SEEDS = {"structured": 7, "tissue": 8}
TOL_RHO, TOL_THETA = 10.0, 0.05
HELD_OUT = 800_000      #: first held-out randomized seed (800000-800099 reserved for evaluation)
RECORDINGS, RAND_FRAMES, RAND_SPAN = 6, 40, 150
MIN_VISIBLE, ABSENT = 40.0, 5.0   #: px of visible edge (540x960)


def _errors(lines, rho, th):
    from graphtrack.geometry.lines import line_difference

    out = []
    for r, t in np.asarray(lines).reshape(-1, 2):
        dr, dt = line_difference(r, t, rho, th)
        j = int(np.argmin(np.abs(dr) / TOL_RHO + np.abs(dt) / TOL_THETA))
        out.append((abs(float(dr[j])), abs(float(dt[j])), j))
    return out


def _set_offsets(d, rho, th) -> list[tuple[float, float]]:
    """(carried, heatmap) signed inward offset (px) of each line-intensities set of
    detection d from its nearest true limb (rho, th (2,)): the median over its pixels."""
    import dataclasses

    from graphtrack.detect import make_observation
    from graphtrack.geometry.lines import pixel_residual

    def signed(det):
        out = []
        for pts in make_observation(det, "line-intensities", use_markers=False).pixels:
            r = [np.median(pixel_residual(pts, rho[j], th[j])) for j in range(2)]
            j = int(np.argmin(np.abs(r)))
            o = 1 - j
            inside = rho[o] * np.array([np.cos(th[o]), np.sin(th[o])])   # a point of the other limb
            out.append(float(r[j] * np.sign(pixel_residual(inside[None], rho[j], th[j])[0])))
        return out
    plain = dataclasses.replace(d, refined=np.zeros(0, bool))
    a, b = signed(d), signed(plain)
    return list(zip(a, b)) if len(a) == len(b) else []


def _both(errors) -> bool:
    """Both true limb lines matched, each by a detected line within tolerance."""
    return len({j for dr, dt, j in errors if dr <= TOL_RHO and dt <= TOL_THETA}) == 2


def _summary(a: dict) -> dict:
    e = np.array(a["err"]).reshape(-1, 3)
    has = len(e) > 0
    sets = np.array(a.get("sets", [])).reshape(-1, 2)
    fig = {}
    if len(sets):
        fig = {"set_px": round(float(np.median(np.abs(sets[:, 0]))), 2),
               "set_in_px": round(float(np.median(sets[:, 0])), 2),
               "set_px_heatmap": round(float(np.median(np.abs(sets[:, 1]))), 2),
               "set_in_px_heatmap": round(float(np.median(sets[:, 1])), 2)}
    return {**fig, "both": round(a["both"] / max(a["n"], 1), 3),
            "rho_px": round(float(np.median(e[:, 0])), 2) if has else None,
            "rho_p90": round(float(np.percentile(e[:, 0], 90)), 2) if has else None,
            "theta_rad": round(float(np.median(e[:, 1])), 4) if has else None,
            "ms": round(float(np.median(a["ms"])), 1) if a["ms"] else None,
            "frames": a["n"]}


def _detectors(sold2=None, weights=None) -> dict:
    """canny, learned (shipped weights), sold2 with a checkpoint, and ``learned:NAME``
    for each NAME=PATH in ``weights``."""
    from graphtrack.detect import make_detector

    dets = {"canny": make_detector("canny"), "learned": make_detector("learned")}
    if sold2:
        dets["sold2"] = make_detector("sold2", weights=sold2)
    for item in weights or ():
        name, _, path = item.partition("=")
        dets[f"learned:{name}"] = make_detector("learned", weights=path)
    return dets


def _standard(dets: dict, frames: int, log) -> dict:
    """The plain recordings SEEDS: {detector: {scene: {mode: figures}}}."""
    from graphtrack.detect import detect_raw
    from graphtrack.robot.features import base_features, shaft_lines
    from graphtrack.sim.simulate import Simulation

    out: dict = {}
    for scene, seed in SEEDS.items():
        sim = Simulation(scene, frames, seed=seed, size=(540, 960))
        cam = sim.camera
        rng = np.random.default_rng(seed)
        acc = {(n, m): {"both": 0, "err": [], "ms": [], "n": 0} for n in dets for m in ("free", "gated")}
        for i in range(frames):
            raw = sim.render(i)[0]
            rho, th, ok = shaft_lines(base_features(sim.robot, sim.q_read[i]).transformed(sim.E_t[i]), cam.K)
            if not ok:
                continue
            pred = np.stack([rho + rng.normal(0, 5.0, 2), th + rng.normal(0, 0.03, 2)], 1)
            for name, det in dets.items():
                for mode, p in (("free", None), ("gated", pred)):
                    d = detect_raw(det, raw, cam, p)
                    a = acc[(name, mode)]
                    e = _errors(d.shaft_lines, rho, th)
                    a["n"] += 1
                    a["ms"].append(d.ms)
                    a["err"] += e
                    a["both"] += int(_both(e))
                    a.setdefault("sets", []).extend(_set_offsets(d, rho, th))
        for (name, mode), a in acc.items():
            out.setdefault(name, {}).setdefault(scene, {})[mode] = _summary(a)
            log(f"{name:16s} {scene:10s} {mode:5s} " + json.dumps(out[name][scene][mode]))
    return out


def visibility(sim, i: int) -> tuple[np.ndarray, float]:
    """(visible px of each true shaft edge (0-2 values), fraction of the in-image
    edge length hidden by an occluder) at frame i; see the module doc."""
    from graphtrack.training.data import visible_runs
    from graphtrack.training.labels import shaft_edge_segments

    cam = sim.camera
    segs = shaft_edge_segments(sim.robot, sim.q_read[i], sim.E_t[i], cam.K, cam.height, cam.width)
    flap = sim.scene.flap_mask(i)
    full = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])
    vis = np.array([sum(float(np.hypot(*(r[2:] - r[:2]))) for r in visible_runs(s, cam, flap, 1.0)) for s in segs])
    hidden = 1.0 - vis.sum() / full.sum() if full.sum() > 0 else 0.0
    return vis, float(hidden)


def _category(vis: np.ndarray, hidden: float) -> str:
    if len(vis) == 2 and vis.min() >= MIN_VISIBLE:
        return "clear" if hidden <= 0.0 else "occluded"
    return "absent" if vis.sum() < ABSENT else "marginal"


def _randomized(dets: dict, recordings: int, frames: int, log) -> dict:
    """The held-out randomized recordings: {detector: {category: {mode: figures}}} + counts."""
    from graphtrack.detect import detect_raw
    from graphtrack.robot.features import base_features, shaft_lines
    from graphtrack.sim.scene import SCENES
    from graphtrack.sim.simulate import Simulation

    acc: dict = {}
    sweep: dict = {}
    counts = {c: 0 for c in ("clear", "occluded", "absent", "marginal")}
    for scene in SCENES:
        for k in range(recordings):
            sim = Simulation(scene, RAND_SPAN, seed=HELD_OUT + k, size=(540, 960), randomize=True)
            cam = sim.camera
            rng = np.random.default_rng(HELD_OUT + k)
            for i in np.linspace(0, RAND_SPAN - 1, min(frames, RAND_SPAN)).round().astype(int).tolist():
                cat = _category(*visibility(sim, i))
                counts[cat] += 1
                if cat == "marginal":
                    continue
                raw = sim.render(i)[0]
                rho, th, ok = shaft_lines(base_features(sim.robot, sim.q_read[i]).transformed(sim.E_t[i]), cam.K)
                pred = np.stack([rho + rng.normal(0, 5.0, 2), th + rng.normal(0, 0.03, 2)], 1) if ok else None
                free = {}
                for name, det in dets.items():
                    for mode, p in (("free", None), ("gated", pred)):
                        if mode == "gated" and p is None:
                            continue
                        d = detect_raw(det, raw, cam, p)
                        if mode == "free":
                            free[name] = d
                        a = acc.setdefault((name, cat, mode), {"both": 0, "err": [], "ms": [], "n": 0, "false": 0})
                        a["n"] += 1
                        a["ms"].append(d.ms)
                        if cat == "absent":
                            a["false"] += int(len(d.shaft_lines) > 0)
                            continue
                        e = _errors(d.shaft_lines, rho, th)
                        a["err"] += e
                        a["both"] += int(_both(e))
                        a.setdefault("sets", []).extend(_set_offsets(d, rho, th))
                if cat == "clear":
                    sweep_frame(dets, sweep, sim, i, raw, rho, th, HELD_OUT + k, _errors, _both, free)
        log(f"randomized {scene}: {counts}")
    out: dict = {"seeds": f"{HELD_OUT}-{HELD_OUT + recordings - 1} per scene", "frames": counts}
    for (name, cat, mode), a in sorted(acc.items()):
        fig = ({"false": round(a["false"] / max(a["n"], 1), 3), "frames": a["n"]} if cat == "absent"
               else _summary(a))
        out.setdefault(name, {}).setdefault(cat, {})[mode] = fig
        log(f"{name:16s} {cat:9s} {mode:5s} " + json.dumps(fig))
    for (name, mode, c), a in sweep.items():     # in SWEEP's order per detector
        fig = {"mode": mode, "c": c, **_summary(a), "edge_contrast": round(float(np.nanmedian(a["contrast"])), 1)}
        out.setdefault(name, {}).setdefault("contrast", []).append(fig)
        log(f"{name:16s} {mode:8s} x{c:<5} " + json.dumps(fig))
    return out


def _table(std: dict, rnd: dict) -> str:
    """Markdown: per detector, free mode, standard scenes and randomized categories."""
    head = ("| detector | structured both / rho med / p90 | tissue both / rho med / p90 "
            "| rand. clear both / rho med / p90 | rand. occluded both / rho med / p90 | rand. absent: false |")
    rows = [head, "|" + "---|" * 6]

    def f(x):
        return "-" if not x else f"{x['both']:.3f} / {x['rho_px']} / {x['rho_p90']}"
    for name in std:
        r = rnd.get(name, {})
        rows.append(f"| {name} | {f(std[name]['structured']['free'])} | {f(std[name]['tissue']['free'])} | "
                    f"{f(r.get('clear', {}).get('free'))} | {f(r.get('occluded', {}).get('free'))} | "
                    f"{r.get('absent', {}).get('free', {}).get('false', '-')} |")
    return "\n".join(rows)


def _sets_table(std: dict, rnd: dict) -> str:
    """Markdown: the line-intensities sets' offsets from the true limbs, free mode."""
    rows = ["| detector | structured | tissue | rand. clear | rand. occluded |", "|" + "---|" * 5]

    def f(x):
        return "-" if not x or "set_px" not in x else (
            f"{x['set_px']} / {x['set_px_heatmap']} ({x['set_in_px']:+} / {x['set_in_px_heatmap']:+})")
    for name in std:
        r = rnd.get(name, {})
        rows.append(f"| {name} | {f(std[name]['structured']['free'])} | {f(std[name]['tissue']['free'])} | "
                    f"{f(r.get('clear', {}).get('free'))} | {f(r.get('occluded', {}).get('free'))} |")
    return "\n".join(rows)


def run(results: dict, frames: int = FRAMES, sold2: str | None = None, log=print, recordings: int = RECORDINGS,
        rand_frames: int = RAND_FRAMES, weights=None) -> dict:
    """Fill results["detect"]: the standard figures per detector, ["randomized"], ["tables"]."""
    from graphtrack.threads import limit_threads

    limit_threads(1)
    dets = _detectors(sold2, weights)
    out = _standard(dets, frames, log) if frames > 0 else {}
    if recordings > 0:
        out["randomized"] = _randomized(dets, recordings, rand_frames, log)
        if out.get("canny"):
            std = {k: v for k, v in out.items() if k not in ("randomized", "tables")}
            out["tables"] = {
                "free mode: both-edges rate / median / p90 |d_rho| px": _table(std, out["randomized"]),
                "free mode: line-intensities sets, median |offset| px carried / as the heatmap gives them "
                "(median signed offset, + into the shaft)": _sets_table(std, out["randomized"]),
                "free mode, randomized clear frames made darker (contrast about the frame's mean, or "
                "light, x c; + N(0, 2^2) gray levels of noise): both-edges rate / median |d_rho| px":
                    contrast_table(out["randomized"])}
    results["detect"] = out
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=FRAMES, help="frames per standard recording (0: skip them)")
    ap.add_argument("--recordings", type=int, default=RECORDINGS,
                    help="held-out randomized recordings per scene (0: skip them)")
    ap.add_argument("--rand-frames", type=int, default=RAND_FRAMES, help="frames per randomized recording")
    ap.add_argument("--sold2", metavar="CKPT", help="SOLD2 checkpoint to include the sold2 detector")
    ap.add_argument("--weights", nargs="*", metavar="NAME=PT", help="more learned-detector weights to compare")
    ap.add_argument("--json", metavar="FILE", help="also write the figures here")
    a = ap.parse_args(argv)
    res: dict = {}
    run(res, a.frames, a.sold2, recordings=a.recordings, rand_frames=a.rand_frames, weights=a.weights)
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
