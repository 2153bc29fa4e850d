"""Robustness of the online estimators on randomized recordings (issue #18).

    python3 benchmarks/bench_robustness.py [--recordings 200] [--workers 2] [--ray local]
    python3 benchmarks/run_all.py robustness          # the default set, into RESULTS.md

Recordings: ``--recordings`` randomized recordings (``graphtrack simulate
--randomize``, JPEG frames; docs/randomized-recordings.md) with seeds SEED0,
SEED0 + 1, ... — held out: no default was tuned and the detector was not
trained on them — of 90-150 frames (drawn from the seed) at 540x960, the
scenes alternating tissue / structured. Each draws a hand-eye error of up to
10 mm / 5 deg, occlusions, the tool leaving the view, smoke, blur, ...

Cells (:mod:`graphtrack.study`, local processes or Ray): kinematics, pf,
smoother and batch with the learned detector and ``line-intensities``.

Per recording and estimator (:mod:`graphtrack.eval.robustness`), from the
per-frame 2-D tip error against the exact tip (truth_errors.csv, tip2d_px)
and the disturbances in scenario.json (every occlusion interval and every
interval with the shaft out of view; evaluation only, the estimators never
read it): the mean tip error; frames to converge (the first visible
segment: the frame from which the error stays below 5 px; a first segment
cut by a disturbance before 15 frames is not judged); frames to re-acquire
after each disturbance; the worst 10-frame window minus the kinematics'.

The particle filter runs PF_SEEDS times per recording (seeds 0, 1, 2): on 200
recordings its fractions differ by up to 0.05 between two seeds
(docs/decisions/pf-seed-spread.md). Its target figures are the mean over the
seeds; the table lists each seed's row beside it.

Aggregates: p50 / p95 / max of the per-recording mean error; the fraction of
recordings converged within 15 frames; the fraction never worse than no
tracking over any 10-frame window (by more than WORSE_TOL_PX: differences
under a pixel are the detector's noise, not a failure; the strict fraction is
reported too); the fraction of re-acquisitions within 15 frames; smoother
p95 / batch p95. Plot: robustness.png (per-recording mean error, CDF).

The causal bound: on the recordings whose first disturbance comes after frame
15, the fraction on which the batch run on frames 0-15 alone has its tip
within 5 px at frame 15 (what those frames allow an online estimator with
these observation models), beside each online estimator's fraction there; and
the same 15 frames after each disturbance, the batch run on frames 0..a+15
(a: the disturbance's end), on every visible segment longer than 15 frames
(docs/decisions/causal-bound.md).
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
DATA = Path(os.environ.get("GRAPHTRACK_BENCH_DATA", HERE / ".data")) / "robustness"
SEED0 = 930_000          # held out: nothing is tuned or trained on 930000-930999 (900000-920199 were
#                          looked at while diagnosing failures, so no longer count as unseen)
TUNING_SEED0 = 700_000   # tuning: defaults may be chosen on 700000-700999
RECORDINGS = 200
FRAMES = (90, 150)
ESTIMATORS = ["kinematics", "pf", "smoother", "batch"]
ONLINE = ("pf", "smoother")
OBSERVATION = "line-intensities"
LIMIT = 15               # frames to converge / re-acquire
WORSE_TOL_PX = 1.0
PF_SEEDS = 3             # the particle filter's runs per recording (seeds 0 .. PF_SEEDS - 1)


def recording_spec(i: int, seed0: int = SEED0) -> tuple[str, int, int]:
    """(scene, frames, seed) of the benchmark's i-th recording."""
    seed = seed0 + i
    frames = int(np.random.default_rng(seed).integers(FRAMES[0], FRAMES[1] + 1))
    return ("tissue", "structured")[i % 2], frames, seed


def _simulate(spec) -> str:
    from graphtrack.sim.simulate import RANDOMIZED_VERSION, simulate
    from graphtrack.threads import limit_threads

    limit_threads(1)
    scene, frames, seed = spec
    final = DATA / "recordings" / f"{scene}-{seed}"
    done, version = final / ".complete", f"v{RANDOMIZED_VERSION}\n"
    if not (done.is_file() and done.read_text() == version):   # missing, or made by an older simulator
        for stale in [final, *DATA.glob(f"study-*/runs/{final.name}")]:   # with the cells run on it
            if stale.exists():
                shutil.rmtree(stale)
        simulate(final, scene=scene, frames=frames, seed=seed, size=(540, 960), form="folder", randomize=True,
                 progress=False, image_format="jpeg")
        done.write_text(version)
    return str(final)


def recordings(n: int, workers: int, seed0: int = SEED0) -> list[str]:
    specs = [recording_spec(i, seed0) for i in range(n)]
    if workers <= 1:
        return [_simulate(s) for s in specs]
    import multiprocessing as mp

    with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as ex:
        return list(ex.map(_simulate, specs))


def disturbances(recording: Path) -> list[tuple[int, int]]:
    """Occlusion intervals and shaft-out-of-view intervals of scenario.json, [start, end)."""
    doc = json.loads((Path(recording) / "scenario.json").read_text())
    out = [(int(o["start"]), int(o["end"])) for o in doc.get("occlusions", [])]
    out += [tuple(map(int, iv)) for iv in (doc.get("out_of_view") or {}).get("shaft_out", [])]
    return out


def cell_dir(runs: Path, estimator: str, seed: int = 0) -> Path:
    """The study's folder of one estimator's cell under a recording's ``runs`` folder
    (its ``Cell.key``: the estimator, with the observation model unless kinematics; a
    repeat with seed > 0 adds ``.seed<seed>``)."""
    key = estimator if estimator == "kinematics" else f"{estimator}-{OBSERVATION}"
    return runs / (key if seed == 0 else f"{key}.seed{seed}")


def tip_errors(cell: Path) -> np.ndarray | None:
    """Per-frame 2-D tip error (px) against the exact tip, by frame index; None if the cell failed."""
    if not (cell / "done.json").is_file():
        return None
    return tip_errors_csv(cell / "truth_errors.csv")


def tip_errors_csv(p: Path) -> np.ndarray | None:
    """Per-frame 2-D tip error (px) of one truth_errors.csv, by frame index; None if missing."""
    if not p.is_file():
        return None
    rows = np.genfromtxt(p, delimiter=",", names=True)
    rows = np.atleast_1d(rows)
    n = int(rows["frame"].max()) + 1 if rows.size else 0
    err = np.full(n, np.nan)
    err[rows["frame"].astype(int)] = rows["tip2d_px"]
    return err


def figures(study: Path, paths: list[str], estimators=ESTIMATORS, seed: int = 0) -> dict[str, list[dict]]:
    """Per estimator, one dict of :func:`graphtrack.eval.robustness.recording_figures` per
    recording (the cells of ``seed``; the kinematics baseline has one)."""
    from graphtrack.eval.robustness import recording_figures

    out: dict[str, list[dict]] = {e: [] for e in estimators}
    for path in paths:
        runs = study / "runs" / Path(path).name
        base = tip_errors(cell_dir(runs, "kinematics"))
        dist = disturbances(Path(path))
        for est in out:
            err = base if est == "kinematics" else tip_errors(cell_dir(runs, est, seed))
            if err is None or base is None:
                out[est].append({"failed": True})
                continue
            n = min(len(err), len(base))
            out[est].append(recording_figures(err[:n], base[:n], dist))
    return out


def _judged(frames: float, segment: int) -> bool:
    """A convergence is judged when it happened within LIMIT frames or its segment was longer
    than LIMIT (a segment cut by the next disturbance sooner decides nothing)."""
    return not np.isnan(frames) and (frames <= LIMIT or segment > LIMIT)


def summarise(figs: list[dict]) -> dict:
    ok = [f for f in figs if not f.get("failed")]
    mean = np.array([f["mean_px"] for f in ok], float)
    judged = [f for f in ok if _judged(f["startup_frames"], f["startup_segment"])]
    reacq = [r for f in ok for r, seg in zip(f["reacquire_frames"], f["reacquire_segments"]) if _judged(r, seg)]
    worst = np.array([f["worst_window_excess_px"] for f in ok], float)
    worst = worst[np.isfinite(worst)]
    return {"recordings": len(figs), "failed": len(figs) - len(ok),
            "mean_px_p50": float(np.percentile(mean, 50)) if mean.size else float("nan"),
            "mean_px_p95": float(np.percentile(mean, 95)) if mean.size else float("nan"),
            "mean_px_max": float(mean.max()) if mean.size else float("nan"),
            "converged15": float(np.mean([f["startup_frames"] <= LIMIT for f in judged])) if judged else float("nan"),
            "startup_judged": len(judged),
            "startup_frames_p95": float(np.quantile([f["startup_frames"] for f in judged], 0.95, method="higher")) if judged
            else float("nan"),
            "never_worse": float(np.mean(worst <= WORSE_TOL_PX)) if worst.size else float("nan"),
            "never_worse_strict": float(np.mean(worst <= 0.0)) if worst.size else float("nan"),
            "worst_excess_max_px": float(worst.max()) if worst.size else float("nan"),
            "reacquisitions": len(reacq),
            "reacquired15": float(np.mean(np.asarray(reacq) <= LIMIT)) if reacq else float("nan")}


def _causal_cell(args) -> float | None:
    """Tip error (px) at frame ``at`` of the batch run on frames 0..at of one recording with
    the study's options; None if that run failed. Re-run when the study's smoother or batch
    cell is newer (the batch starts from the online smoother: graphtrack/estimate/batch.py)."""
    path, runs, options, at = args
    from graphtrack.study.cells import Cell
    from graphtrack.threads import limit_threads
    from graphtrack.track import track

    limit_threads(1)
    runs = Path(runs)
    out = runs / f"batch-causal{at}"
    csv = out / "truth_errors.csv"
    newer = [cell_dir(runs, e) / "done.json" for e in ("smoother", "batch")]
    if not csv.is_file() or any(d.is_file() and d.stat().st_mtime > csv.stat().st_mtime for d in newer):
        cell = Cell(runs.name, path, "batch", OBSERVATION, str(out), options)
        try:
            track(path, out, cell.track_options(), progress=False, quiet=True, max_frames=at + 1,
                  topics=cell.topics(), overwrite=True)
        except Exception as exc:  # noqa: BLE001 (a failed cell is counted, as the study counts its own)
            print(f"causal bound: {runs.name} to frame {at}: {exc}", file=sys.stderr)
            return None
    err = tip_errors_csv(csv)
    return float(err[at]) if err is not None and len(err) > at else None


def _bound(study: Path, points: list[tuple[str, int]], options, workers: int) -> dict:
    """At each (recording path, frame ``at``) of ``points``: whether the batch run on frames
    0..at alone has its tip within CONVERGED_PX at ``at`` (the fraction: ``batch``), beside
    each online estimator's own fraction there (the particle filter's: the mean over its
    PF_SEEDS runs; a failed online cell counts as not within); ``judged``: the points whose
    batch run did not fail, ``failed``: those that did (left out)."""
    import multiprocessing as mp

    from graphtrack.eval.robustness import CONVERGED_PX

    runs = [study / "runs" / Path(p).name for p, _ in points]
    jobs = [(p, str(r), options.cell_options(), at) for (p, at), r in zip(points, runs)]
    with ProcessPoolExecutor(max(1, workers), mp_context=mp.get_context("spawn")) as ex:
        tips = list(ex.map(_causal_cell, jobs))
    ok = [(r, at, t) for r, (_, at), t in zip(runs, points, tips) if t is not None]
    res = {"judged": len(ok), "failed": len(tips) - len(ok),
           "batch": float(np.mean([t < CONVERGED_PX for _, _, t in ok])) if ok else float("nan")}

    def within(cell: Path, at: int) -> bool:
        e = tip_errors(cell)
        return e is not None and len(e) > at and e[at] < CONVERGED_PX

    for est in ONLINE:
        seeds = range(PF_SEEDS if est == "pf" else 1)
        res[est] = float(np.mean([within(cell_dir(r, est, s), at) for r, at, _ in ok for s in seeds])) \
            if ok else float("nan")
    return res


def causal_bound(study: Path, paths: list[str], options, workers: int) -> dict:
    """The causal bound (docs/decisions/causal-bound.md), :func:`_bound` at frame LIMIT of
    the recordings whose first disturbance comes after frame LIMIT (start-up), and at frame
    a + LIMIT of every visible segment [a, b) after a disturbance with b - a > LIMIT
    (re-acquisition): {"startup": ..., "reacquisition": ...}."""
    from graphtrack.eval.robustness import segments

    startup = [(p, LIMIT) for p in paths if all(a > LIMIT for a, _ in disturbances(Path(p)))]
    reacq = []
    for p in paths:
        base = tip_errors(cell_dir(study / "runs" / Path(p).name, "kinematics"))
        if base is not None:
            reacq += [(p, a + LIMIT) for a, b in segments(len(base), disturbances(Path(p)))
                      if a > 0 and b - a > LIMIT]
    return {"startup": _bound(study, startup, options, workers),
            "reacquisition": _bound(study, reacq, options, workers)}


def plot(study: Path, per_est: dict[str, list[dict]]) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401  (ScalarFormatter)

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for est, figs in per_est.items():
        v = np.sort([f["mean_px"] for f in figs if not f.get("failed")])
        if v.size:
            ax.step(v, np.arange(1, v.size + 1) / v.size, where="post", label=est)
    ax.set_xscale("log")
    ax.set_ylim(0, 1.02)
    ax.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax.set_xlabel("per-recording mean 2-D tip error against the exact tip (px, 540x960)")
    ax.set_ylabel("fraction of recordings")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(HERE / "robustness.png", dpi=110)
    plt.close(fig)
    return "robustness.png"


def table(res: dict) -> str:
    keys = [("mean_px_p50", "mean p50 px"), ("mean_px_p95", "mean p95 px"), ("mean_px_max", "mean max px"),
            ("converged15", "converged <= 15 frames"), ("never_worse", "never worse (1 px tol.)"),
            ("never_worse_strict", "never worse (strict)"), ("reacquired15", "re-acquired <= 15 frames"),
            ("reacquisitions", "re-acquisitions"), ("failed", "failed runs")]
    rows = ["| estimator | " + " | ".join(k[1] for k in keys) + " |", "|---" * (len(keys) + 1) + "|"]
    named = [(est, res[est]) for est in ESTIMATORS]
    seeds = res.get("pf_seeds", [])
    if len(seeds) > 1:   # the particle filter per seed, and their mean (the target figures)
        i = ESTIMATORS.index("pf")
        mean = {k: float(np.mean([s[k] for s in seeds])) for k, _ in keys}
        named[i:i + 1] = [(f"pf, seed {j}", s) for j, s in enumerate(seeds)] + [(f"pf, mean of {len(seeds)}", mean)]
    for est, s in named:
        cells = [("–" if est == "kinematics" and k not in ("mean_px_p50", "mean_px_p95", "mean_px_max", "failed")
                  else f"{s[k]:.3g}" if isinstance(s[k], float) else str(s[k])) for k, _ in keys]
        rows.append(f"| {est} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def bound_table(b: dict) -> str:
    """The causal bound (:func:`causal_bound`) as a markdown table."""
    s, r = b["startup"], b["reacquisition"]
    rows = [f"| tip within 5 px | at frame {LIMIT} (start-up) | {LIMIT} frames after a disturbance |",
            "|---|---|---|",
            f"| batch on the frames up to then only (the bound) | {s['batch']:.3g} | {r['batch']:.3g} |"]
    rows += [f"| {est}{', mean of its seeds' if est == 'pf' else ''} | {s[est]:.3g} | {r[est]:.3g} |"
             for est in ONLINE]
    rows.append(f"| judged (start-ups: first disturbance after frame {LIMIT}; re-acquisitions: "
                f"segment longer than {LIMIT} frames) | {s['judged']} | {r['judged']} |")
    return "\n".join(rows)


def run(results: dict, n: int = RECORDINGS, workers: int | None = None, ray: str | None = None,
        seed0: int = SEED0) -> dict:
    from graphtrack.study.cells import StudyOptions
    from graphtrack.study.plan import run_study

    workers = workers or os.cpu_count() or 1
    if hasattr(os, "sched_setaffinity"):  # run_all pins itself to one core; the study may use all
        os.sched_setaffinity(0, set(range(os.cpu_count() or 1)))
    paths = recordings(n, workers, seed0)
    study = DATA / f"study-{seed0}-{n}"
    options = StudyOptions(estimators=ESTIMATORS, observations=[OBSERVATION], repeats=PF_SEEDS)
    run_study(paths, study, options, workers=workers, ray_address=ray, quiet=False)
    per_est = figures(study, paths)
    res = results.setdefault("robustness", {})
    for est, figs in per_est.items():
        res[est] = summarise(figs)
    res["pf_seeds"] = [res["pf"]] + [summarise(figures(study, paths, ["pf"], s)["pf"]) for s in range(1, PF_SEEDS)]
    for est in ONLINE:
        runs = res["pf_seeds"] if est == "pf" else [res[est]]
        for k in ("converged15", "never_worse", "reacquired15"):
            res[f"{k}_{est}"] = float(np.mean([r[k] for r in runs]))
    res["p95_ratio_smoother_batch"] = res["smoother"]["mean_px_p95"] / res["batch"]["mean_px_p95"]
    res["causal_bound"] = causal_bound(study, paths, options, workers)
    res["seeds"] = f"{seed0}-{seed0 + n - 1}"
    res["plots"] = [plot(study, per_est)]
    res.setdefault("tables", {})[f"{n} randomized recordings (seeds {res['seeds']}, held out)"] = table(res)
    res["tables"]["the causal bound: what the frames up to then allow"] = bound_table(res["causal_bound"])
    (study / "robustness.json").write_text(json.dumps({"summary": res, "per_recording": per_est}, indent=1,
                                                      default=float))
    print(table(res))
    return results


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recordings", type=int, default=RECORDINGS)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--ray", default=None, metavar="ADDRESS", help="run the cells as Ray tasks (e.g. local)")
    ap.add_argument("--seed0", type=int, default=SEED0,
                    help=f"first seed (default {SEED0}, held out; tune on {TUNING_SEED0}+)")
    a = ap.parse_args(argv)
    res = run({}, a.recordings, a.workers, a.ray, a.seed0)
    print(json.dumps({k: v for k, v in res["robustness"].items() if k != "tables"}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(HERE.parent))
    sys.exit(main())
