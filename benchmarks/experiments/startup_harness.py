"""Start-up / re-acquisition experiment on randomized recordings (issue #18):
pf and smoother with and without the global start-up search (``--no-search``).

For each recording folder made by ``graphtrack simulate OUT --randomize``:
tracks it with the CLI (learned detector, ``line-intensities`` + markers), reads
the per-frame tip error (truth_errors.csv, tip2d_px) and computes
:func:`graphtrack.eval.robustness.recording_figures` against the kinematics
baseline, with the disturbances = scenario.json's occlusion intervals and
shaft-out-of-view intervals. The estimators never read truth or scenario.json;
only this script does.

    python3 benchmarks/experiments/startup_harness.py /tmp/rec/tissue_101 ... --json out.json

(The 200-recording benchmark of the lead replaces this on main; this is the
small tuning-seed experiment of docs/decisions/startup-search.md.)
"""
from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from graphtrack.eval.robustness import recording_figures  # noqa: E402

VARIANTS = {"pf": ["--estimator", "pf"], "pf-nosearch": ["--estimator", "pf", "--no-search"],
            "smoother": ["--estimator", "smoother"], "smoother-nosearch": ["--estimator", "smoother", "--no-search"]}


def tip_errors(out: Path) -> np.ndarray:
    with open(out / "truth_errors.csv") as f:
        return np.array([float(r["tip2d_px"]) if r["tip2d_px"] not in ("", "nan") else np.nan
                         for r in csv.DictReader(f)])


def disturbances(rec: Path) -> list[tuple[int, int]]:
    sc = json.loads((rec / "scenario.json").read_text())
    out = [(o["start"], o["end"]) for o in sc.get("occlusions", [])]
    out += [tuple(iv) for iv in (sc.get("out_of_view") or {}).get("shaft_out", [])]
    return out


def track(rec: Path, out: Path, args: list[str]) -> tuple[np.ndarray, dict]:
    if not (out / "metrics.json").is_file():
        subprocess.run([sys.executable, "-m", "graphtrack.cli", "track", str(rec), "--out", str(out),
                        "--observation", "line-intensities", "--detector", "learned", "--quiet",
                        "--overwrite", *args], check=True, cwd=ROOT)
    return tip_errors(out), json.loads((out / "metrics.json").read_text())


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("recordings", nargs="+")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--work", default="/tmp/graphtrack_startup_harness")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    rows = []
    for rec in map(Path, a.recordings):
        work = Path(a.work) / rec.name
        base, _ = track(rec, work / "kinematics", ["--estimator", "kinematics"])
        dist = disturbances(rec)
        for v in a.variants:
            err, metrics = track(rec, work / v, VARIANTS[v])
            fig = recording_figures(err, base, dist)
            fig.update(recording=rec.name, variant=v, kinematics_px=float(np.nanmean(base)),
                       estimate_ms=metrics.get("timing_ms_median", {}).get("estimate"),
                       no_detection_stretches=metrics.get("no_detection_stretches"), disturbances=dist)
            rows.append(fig)
            print(json.dumps(fig), flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
