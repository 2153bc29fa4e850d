"""Accuracy of every estimator x observation model on simulated recordings (Table I).

    python benchmarks/bench_accuracy.py       # or through benchmarks/run_all.py

Two recordings that no default was tuned on (seed 7 structured, seed 8
tissue; FRAMES frames at 540x960) go through `graphtrack compare` with the
learned detector: kinematics, the particle filter, the fixed-lag smoother and
the batch refinement, each with all six observation models, all on the same
detections. Reported: mean 2-D tip error (px, against labels.csv) per cell,
and the issue targets: the PF with line-intensities + markers at least halves
the kinematics error on both scenes; smoother <= PF for each shared model;
batch <= smoother. labels.csv carries the simulator's N(0, 1.2 px) labelling
noise per axis, so the same comparisons are also counted against the exact
truth (each run's metrics.json: 2-D tip px and 3-D tip mm), which decides
differences of a few hundredths of a pixel that the labels cannot.

Seed-dependent cells (the particle filter; the RANSAC -polar models for every
estimator) run with REPEATS seeds (the study's ``repeats``) and the tables
compare their means: one seed of a particle filter is one draw (on the
structured recording four filter seeds of line-intensities-polar gave
4.5-9.5 px). The seed-0 figures alone are reported too.

Each target is also given as a paired difference per frame (a - b, the
estimators' errors on the same frames, averaged over their seeds) with a 95 %
moving-block bootstrap interval: an interval holding 0 means the 300 frames
do not decide the order. With the learned detector the ``canny`` model's lines
are the associated detector lines, i.e. the lines through the segments'
endpoints, so its row equals ``endpoints-polar``'s.
"""
from __future__ import annotations

import csv
import functools
import os
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DATA = Path(os.environ.get("GRAPHTRACK_BENCH_DATA", HERE / ".data"))
FRAMES = 300
RECORDINGS = (("structured", 7), ("tissue", 8))
ESTIMATORS = ("kinematics", "pf", "smoother", "batch")
REPEATS = 5
#: local worker processes for the study's cells (accuracy does not depend on it): every core
WORKERS = int(os.environ.get("GRAPHTRACK_BENCH_WORKERS", str(os.cpu_count() or 1)))


def run(results: dict) -> dict:
    from graphtrack.detect.base import OBSERVATION_MODELS
    from graphtrack.study import StudyOptions, run_study
    from graphtrack.sim.simulate import simulated_once

    if WORKERS > 1 and hasattr(os, "sched_setaffinity"):  # run_all pins itself to one core
        os.sched_setaffinity(0, set(range(os.cpu_count() or 1)))
    paths = []
    for scene, seed in RECORDINGS:
        p = simulated_once(DATA / f"acc-{scene}-{seed}-{FRAMES}", scene=scene, frames=FRAMES, seed=seed,
                           size=(540, 960), progress=True)
        paths.append(str(p))
    out = DATA / "accuracy-study"
    run_study(paths, out, StudyOptions(estimators=list(ESTIMATORS), observations=list(OBSERVATION_MODELS),
                                       repeats=REPEATS), workers=WORKERS, names=[s for s, _ in RECORDINGS])
    runs: dict = {}   # (recording, estimator, observation) -> {seed: mean tip px}
    truth: dict = {}  # the same against the exact truth: {seed: (2-D px, 3-D mm)}
    states: dict = {}  # (recording, estimator, observation) -> {seed: the run's state}
    with open(out / "results.csv") as f:
        for row in csv.DictReader(f):
            try:
                v = float(row["tip_error_px.mean"])
            except ValueError:
                v = float("nan")
            k = (row["recording"], row["estimator"], row["observation"])
            runs.setdefault(k, {})[int(row["seed"])] = v
            states.setdefault(k, {})[int(row["seed"])] = row.get("state", "")
            if row["estimator"] != "kinematics":      # (the table has no truth row for it)
                truth.setdefault(k, {})[int(row["seed"])] = (out, row.get("state") == "done")
    for k, v in truth.items():   # the study's folders: the first repeat (lowest seed) without a suffix
        first = min(v)
        for seed, (out_dir, done) in list(v.items()):
            folder = f"{k[1]}-{k[2]}" + ("" if seed == first else f".seed{seed}")
            v[seed] = _truth_tip(out_dir / "runs" / k[0] / folder) if done else (float("nan"), float("nan"))
    cells = {k: sum(v.values()) / len(v) for k, v in runs.items()}      # mean over the seeds
    seed0 = {k: v[min(v)] for k, v in runs.items()}                      # the study's own seed
    res = results.setdefault("accuracy", {})
    scenes = [s for s, _ in RECORDINGS]
    kin = {s: next(v for (r, e, _), v in cells.items() if r == s and e == "kinematics") for s in scenes}
    header = "| observation model | " + " | ".join(f"{e} {s}" for s in scenes for e in ESTIMATORS[1:]) + " |"
    sep = "|---" * (1 + len(scenes) * 3) + "|"
    rows = [header, sep,
            "| (kinematics, no correction) | " + " | ".join(
                f"{kin[s]:.2f}" if e == "pf" else "" for s in scenes for e in ESTIMATORS[1:]) + " |"]
    for m in OBSERVATION_MODELS:
        vals = [cells.get((s, e, m), float("nan")) for s in scenes for e in ESTIMATORS[1:]]
        rows.append(f"| {m} | " + " | ".join(f"{v:.2f}" for v in vals) + " |")
    table = "mean 2-D tip error (px), same recordings; seed-dependent cells: mean over %d seeds" % REPEATS
    res.setdefault("tables", {})[table] = "\n".join(rows)
    spread = [header.replace("| observation model |", "| observation model (seeds: min - max) |"), sep]
    for m in OBSERVATION_MODELS:
        vals = []
        for s in scenes:
            for e in ESTIMATORS[1:]:
                v = runs.get((s, e, m), {})
                vals.append(f"{min(v.values()):.2f} - {max(v.values()):.2f}" if len(v) > 1 else "1 seed")
        spread.append(f"| {m} | " + " | ".join(vals) + " |")
    res["tables"]["per-seed spread of the mean 2-D tip error (px)"] = "\n".join(spread)
    shared = [m for m in OBSERVATION_MODELS if m != "endpoints-polar"]
    for s in scenes:
        res[f"kinematics_px_{s}"] = kin[s]
        pf = cells.get((s, "pf", "line-intensities"), float("nan"))
        res[f"pf_line_intensities_px_{s}"] = pf
        res[f"pf_halves_kinematics_{s}"] = bool(pf <= kin[s] / 2)
        for tag, src in (("", cells), ("_seed0_only", seed0)):
            res[f"smoother_le_pf_models_{s}{tag}"] = sum(
                src.get((s, "smoother", m), 1e9) <= src.get((s, "pf", m), -1) for m in shared)
            res[f"batch_le_smoother_models_{s}{tag}"] = sum(
                src.get((s, "batch", m), 1e9) <= src.get((s, "smoother", m), -1) for m in OBSERVATION_MODELS)
    # labels.csv carries N(0, 1.2 px) labelling noise per axis; the simulator's exact
    # truth (truth_errors.csv of each run) decides differences of a few hundredths
    for i, unit in ((0, "px"), (1, "mm")):
        tcells = {k: sum(t[i] for t in v.values()) / len(v) for k, v in truth.items()}
        for s in scenes:
            res[f"batch_le_smoother_models_{s}_truth_{'2d_px' if i == 0 else '3d_mm'}"] = sum(
                tcells.get((s, "batch", m), 1e9) <= tcells.get((s, "smoother", m), -1) for m in OBSERVATION_MODELS)
        trows = [header.replace("| observation model |", f"| observation model (against the truth, {unit}) |"),
                 sep]
        for m in OBSERVATION_MODELS:
            vals = [tcells.get((s, e, m), float("nan")) for s in scenes for e in ESTIMATORS[1:]]
            trows.append(f"| {m} | " + " | ".join(f"{v:.2f}" for v in vals) + " |")
        name = "mean 2-D tip error against the exact truth (px)" if i == 0 else "mean 3-D tip error (mm)"
        res["tables"][name] = "\n".join(trows)
    res["tables"].update(_paired_tables(out, dict(zip(scenes, paths)), states, shared))
    res["shared_models"] = len(shared)
    # relative to the repository (RESULTS.md quotes it; a machine's absolute path means nothing elsewhere)
    res["study_folder"] = os.path.relpath(out, HERE.parent)
    for line in rows + [""] + spread:
        print(line)
    return results


#: the paired comparisons of the targets: (a, b, models) -> a - b
PAIRS = (("smoother", "pf"), ("batch", "smoother"))


def _paired_tables(out: Path, recordings: dict, states: dict, shared: list) -> dict:
    """Per scene and model, the per-frame paired difference of the 2-D tip error
    (a - b, px, each estimator's errors averaged over its seeds frame by frame)
    with its 95 % moving-block bootstrap interval
    (:func:`graphtrack.eval.metrics.paired_difference`), against labels.csv and
    against the exact truth. An interval that holds 0 means the recording does
    not decide the order of the two estimators. ``states``: (recording,
    estimator, model) -> {seed: the run's state in results.csv}; a cell with a
    run that is not done is NaN (as in the tables of means), not the mean of
    the seeds that finished, nor a failed run's partial trajectory."""
    from graphtrack.detect.base import OBSERVATION_MODELS
    from graphtrack.eval.metrics import paired_difference, tip_errors
    from graphtrack.io.labels import read_labels
    from graphtrack.io.trajectory import read_trajectory

    refs = {}
    for s, p in recordings.items():
        t = read_trajectory(Path(p) / "truth.csv")
        refs[s] = {"labels": read_labels(Path(p) / "labels.csv"),
                   "truth": {int(f): tip for f, tip in zip(t["frame"], t["tip"])}}

    @functools.lru_cache(maxsize=None)   # the smoother's errors serve both tables: read each run once
    def per_frame(s, est, m, ref):   # per labelled frame, the mean error over the cell's seeds
        runs = states.get((s, est, m), {})
        frames = sorted(refs[s][ref])
        if not runs or any(state != "done" for state in runs.values()):
            return np.full(len(frames), np.nan)
        seeds = sorted(runs)
        acc = np.full((len(seeds), len(frames)), np.nan)
        for i, seed in enumerate(seeds):
            folder = out / "runs" / s / (f"{est}-{m}" + ("" if seed == seeds[0] else f".seed{seed}"))
            tr = read_trajectory(folder / "trajectory.csv")
            f, e = tip_errors(tr["frame"], tr["tip"], refs[s][ref])
            acc[i, np.searchsorted(frames, f)] = e
        # a frame a run skipped is NaN in that run: the frame's mean is over the runs that scored it
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return np.nanmean(acc, axis=0)

    tables = {}
    for a, b in PAIRS:
        models = shared if b == "pf" else list(OBSERVATION_MODELS)
        head = "| observation model | " + " | ".join(f"{s}, {ref}" for s in recordings
                                                    for ref in ("labels", "truth")) + " |"
        rows = [head, "|---" * (1 + 2 * len(recordings)) + "|"]
        for m in models:
            vals = []
            for s in recordings:
                for ref in ("labels", "truth"):
                    r = paired_difference(per_frame(s, a, m, ref), per_frame(s, b, m, ref))
                    vals.append(f"{r['mean']:+.2f} [{r['low']:+.2f}, {r['high']:+.2f}]")
            rows.append(f"| {m} | " + " | ".join(vals) + " |")
        tables[f"paired difference {a} - {b} of the 2-D tip error (px), per frame, 95 % block-bootstrap "
               f"interval (1 s blocks); negative: {a} better"] = "\n".join(rows)
    return tables


def _truth_tip(run: Path) -> tuple[float, float]:
    """Mean 2-D tip error (px) and 3-D tip error (mm) of one run against the
    simulator's exact truth (its metrics.json, non-finite frames dropped; NaN when
    missing)."""
    import json

    try:
        m = json.loads((run / "metrics.json").read_text())
        return float(m["tip_error_vs_truth_px"]["mean"]), float(m["tip_error_3d_mm"]["mean"])
    except (OSError, KeyError, ValueError, TypeError):
        return float("nan"), float("nan")


if __name__ == "__main__":
    run({})
