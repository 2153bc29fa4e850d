"""A shaft along an image axis: the learned detector and the online estimators with and
without the turned net input (docs/decisions/net-orientation.md).

    python3 benchmarks/bench_orientation.py [--recordings 16] [--workers 2]
    python3 benchmarks/run_all.py orientation

The simulator draws the shaft entering 20-65 deg from the horizontal, and so did the
learned detector's training frames; a lab's endoscope sees the tool at any angle.
Recordings: ``--recordings`` randomized recordings (as the robustness benchmark's:
occlusions, out-of-view excursions, smoke, hand-eye errors up to 10 mm / 5 deg) of
FRAMES frames at 540x960 with seeds SEED0 + i, held out (nothing was tuned or trained
on them), the shaft entering from the right, top, left or bottom (``ANGLES``, offset by
OFFSET_DEG on every other group of four), scenes in pairs.

Per variant (``turn``: the detector as shipped, ``no-turn``: ``--no-turn``):

- detection: on every DETECT_EVERY-th frame whose both edges are clear (bench_detect's
  classes), the fraction with both edges found (bench_detect's tolerances), gated with
  the true limb lines as the prediction, as the tracker passes them;
- tracking, learned detector + ``line-intensities``, smoother and particle filter (seed 0):
  the robustness benchmark's per-recording figures against the kinematics baseline
  (bench_robustness.summarise: mean tip error p50 / p95 / max, converged within 15
  frames, never worse than no tracking by more than 1 px over 10 frames).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[0]))  # runnable from a checkout
sys.path.insert(0, str(HERE))
DATA = Path(os.environ.get("GRAPHTRACK_BENCH_DATA", HERE / ".data")) / "orientation"
SEED0 = 960_000          # held out: nothing is tuned or trained on 960000-960999
RECORDINGS = 16
FRAMES = 90
ANGLES = (0.0, 90.0, 180.0, 270.0)   # from the right, top, left, bottom
OFFSET_DEG = 10.0
DETECT_EVERY = 10
VARIANTS = ("turn", "no-turn")
ESTIMATORS = ("smoother", "pf")


def spec(i: int) -> tuple[str, int, float]:
    """(scene, seed, shaft angle deg) of the i-th recording."""
    return ("tissue", "structured")[(i // 2) % 2], SEED0 + i, ANGLES[i % 4] + OFFSET_DEG * ((i // 4) % 2)


def _simulate(scene: str, seed: int, angle: float) -> Path:
    from graphtrack.sim.simulate import RANDOMIZED_VERSION, simulate

    path = DATA / f"{scene}-{seed}-{angle:g}"
    done, version = path / ".complete", f"v{RANDOMIZED_VERSION}\n"
    if not (done.is_file() and done.read_text() == version):
        if path.exists():
            shutil.rmtree(path)
        simulate(path, scene=scene, frames=FRAMES, seed=seed, size=(540, 960), form="folder", randomize=True,
                 progress=False, image_format="jpeg", shaft_angle=angle)
        done.write_text(version)
    return path


def _detection(scene: str, seed: int, angle: float) -> dict:
    """Per variant: [clear frames, of them with both edges found]."""
    from bench_detect import _both, _category, _errors, visibility

    from graphtrack.detect.learned import LearnedDetector
    from graphtrack.robot.features import base_features, shaft_lines
    from graphtrack.sim.simulate import Simulation

    sim = Simulation(scene, FRAMES, seed, (540, 960), randomize=True, shaft_angle=angle)
    dets = {v: LearnedDetector(turn=v == "turn") for v in VARIANTS}
    out = {v: [0, 0] for v in VARIANTS}
    for k in range(0, FRAMES, DETECT_EVERY):
        if _category(*visibility(sim, k)) != "clear":
            continue
        raw, _ = sim.render(k)
        rho, th, _ = shaft_lines(base_features(sim.robot, sim.q_read[k]).transformed(sim.E_t[k]), sim.camera.K)
        for v, det in dets.items():
            d = det.detect(raw, np.stack([rho, th], 1), camera=sim.camera)
            out[v][0] += 1
            out[v][1] += int(_both(_errors(d.shaft_lines, rho, th)))
    return out


def _recording(i: int) -> dict:
    """One recording: its detection counts and each variant's and estimator's figures."""
    from bench_robustness import OBSERVATION, disturbances, tip_errors_csv

    from graphtrack.detect.options import DetectionOptions
    from graphtrack.eval.robustness import recording_figures
    from graphtrack.threads import limit_threads
    from graphtrack.track import TrackOptions, track

    limit_threads(1)
    scene, seed, angle = spec(i)
    path = _simulate(scene, seed, angle)
    runs = DATA / "runs" / path.name

    def cell(name: str, estimator: str, turn: bool = True) -> np.ndarray:
        out = runs / name
        if not (out / "truth_errors.csv").is_file():
            opts = TrackOptions(estimator=estimator, observation=OBSERVATION,
                                detection=DetectionOptions(turn=turn))
            track(path, out, opts, progress=False, quiet=True, overwrite=True)
        return tip_errors_csv(out / "truth_errors.csv")

    base = cell("kinematics", "kinematics")
    dist = disturbances(path)
    figs = {}
    for v in VARIANTS:
        for est in ESTIMATORS:
            err = cell(f"{est}-{v}", est, v == "turn")
            n = min(len(err), len(base))
            figs[f"{est}-{v}"] = recording_figures(err[:n], base[:n], dist)
    return {"recording": path.name, "angle": angle, "detection": _detection(scene, seed, angle), "figures": figs}


def run(results: dict, recordings: int = RECORDINGS, workers: int = 2) -> dict:
    import multiprocessing as mp

    from bench_robustness import summarise

    DATA.mkdir(parents=True, exist_ok=True)
    with ProcessPoolExecutor(max(1, workers), mp_context=mp.get_context("spawn")) as ex:
        per = list(ex.map(_recording, range(recordings)))
    out = results.setdefault("orientation", {})
    out["recordings"] = [p["recording"] for p in per]
    rows = ["| variant | both edges found (clear frames) | estimator | mean tip px p50 / p95 / max | "
            "converged <= 15 | never worse |", "|---|---|---|---|---|---|"]
    for v in VARIANTS:
        frames = sum(p["detection"][v][0] for p in per)
        found = sum(p["detection"][v][1] for p in per)
        out[f"both_{v}"] = found / frames if frames else float("nan")
        out["clear_frames"] = frames
        for est in ESTIMATORS:
            s = summarise([p["figures"][f"{est}-{v}"] for p in per])
            out[f"{est}_{v}"] = {k: s[k] for k in ("mean_px_p50", "mean_px_p95", "mean_px_max", "converged15",
                                                  "never_worse")}
            rows.append(f"| {v} | {out[f'both_{v}']:.3f} | {est} | {s['mean_px_p50']:.2f} / {s['mean_px_p95']:.2f} / "
                        f"{s['mean_px_max']:.2f} | {s['converged15']:.3f} | {s['never_worse']:.3f} |")
    out["tables"] = {f"shaft along an image axis, {recordings} held-out randomized recordings": "\n".join(rows)}
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--recordings", type=int, default=RECORDINGS)
    p.add_argument("--workers", type=int, default=2)
    args = p.parse_args(argv)
    res = run({}, args.recordings, args.workers)
    print(json.dumps({k: v for k, v in res.items() if k != "tables"}, indent=1))
    print(next(iter(res["tables"].values())))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
