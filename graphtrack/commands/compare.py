"""``graphtrack compare SEQ... --out DIR``: every estimator x observation model on every recording."""
from __future__ import annotations

import sys

from graphtrack.detect.base import OBSERVATION_MODELS
from graphtrack.errors import InputError
from graphtrack.estimate import ESTIMATORS

DETECTORS = ("canny", "learned", "sold2")


def _list(value: str, allowed, what: str) -> list[str]:
    if value.strip() == "all":
        return list(allowed)
    items = [v.strip() for v in value.split(",") if v.strip()]
    bad = [v for v in items if v not in allowed]
    if bad or not items:
        why = f"unknown {bad[0]!r}" if bad else "empty list"
        raise InputError(f"--{what}: {why} (choose from {', '.join(allowed)}, or all)")
    return list(dict.fromkeys(items))


def study_options_from_args(args):
    from graphtrack.study import StudyOptions

    if args.particles <= 0:
        raise InputError("--particles must be positive")
    if args.lag <= 0:
        raise InputError("--lag must be positive")
    if args.max_frames is not None and args.max_frames <= 0:
        raise InputError("--max-frames must be positive")
    if args.repeats < 1:
        raise InputError("--repeats must be at least 1")
    return StudyOptions(estimators=_list(args.estimators, tuple(ESTIMATORS), "estimators"),
                        observations=_list(args.observations, OBSERVATION_MODELS, "observations"),
                        detector=args.detector, weights=args.weights, max_frames=args.max_frames,
                        particles=args.particles, lag=args.lag, smoother=args.smoother, seed=args.seed,
                        alpha=args.alpha, beta=args.beta, markers=not args.no_markers,
                        repeats=args.repeats)


def run(args) -> int:
    from graphtrack.study import format_table, run_study

    options = study_options_from_args(args)
    data = run_study(args.sequences, args.out, options, workers=args.workers, ray_address=args.ray,
                     quiet=args.quiet)
    if not args.quiet:
        print(format_table(data))
        print(f"\n{data['ran']} cells computed, {data['reused']} reused; "
              f"wrote {args.out}/table.md, table.csv, runtime.csv, results.csv and "
              f"accumulated_error_<recording>.png")
        for n in data["notes"]:
            print(f"note: {n}")
    for rec, key, msg in data["errors"]:
        print(f"graphtrack: cell {rec}/{key} failed: {msg}", file=sys.stderr)
    return 0


def add_parser(sub):
    p = sub.add_parser("compare", help="compare estimators and observation models over recordings",
                       description="Run every estimator x observation-model combination on every "
                                   "recording and write the method's Table I (table.md, table.csv), "
                                   "a runtime table and accumulated-error plots. Resumable: finished "
                                   "cells (done.json) are reused.")
    p.add_argument("sequences", nargs="+", metavar="SEQ", help="recording folders")
    p.add_argument("--out", required=True, metavar="DIR", help="study folder")
    p.add_argument("--estimators", default="kinematics,pf,smoother,batch",
                   help="comma-separated, or all (default: kinematics,pf,smoother,batch)")
    p.add_argument("--observations", default="all",
                   help="comma-separated observation models, or all: the six models (default)")
    p.add_argument("--workers", type=int, default=1, metavar="N", help="local worker processes (default 1)")
    p.add_argument("--ray", metavar="ADDRESS", default=None,
                   help="run cells as Ray tasks: 'local' (start one here), 'auto' or a cluster address")
    p.add_argument("--detector", choices=DETECTORS, default="learned")
    p.add_argument("--weights", metavar="FILE", help="weights for --detector learned/sold2")
    p.add_argument("--no-markers", action="store_true", help="do not use painted-marker features")
    p.add_argument("--particles", type=int, default=1000, help="particle filter: number of particles")
    p.add_argument("--lag", type=float, default=1.0, metavar="SECONDS", help="smoother: fixed lag")
    p.add_argument("--smoother", choices=("isam2", "batch"), default="isam2")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--repeats", type=int, default=1, metavar="N",
                   help="run each seed-dependent cell (the particle filter; the RANSAC -polar models) "
                        "with seeds SEED..SEED+N-1 and report their mean (default 1)")
    p.add_argument("--alpha", type=float, default=10.0, help="pixel-set radius alpha (px)")
    p.add_argument("--beta", type=float, default=0.9, help="pixel-set heatmap threshold beta")
    p.add_argument("--max-frames", type=int, default=None, metavar="N")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
