"""``graphtrack compare SEQ... --out DIR``: every estimator x observation model on every recording."""
from __future__ import annotations

import sys

from graphtrack.commands.common import add_source_arguments, output_path, source_from_args
from graphtrack.io.run_output import check_run_arguments, outside_recording
from graphtrack.commands.track import (FORMATTER, add_detection_arguments, add_estimator_arguments,
                                       add_turn_argument, estimator_options_from_args)
from graphtrack.detect.base import OBSERVATION_MODELS
from graphtrack.detect.options import DetectionOptions
from graphtrack.errors import InputError
from graphtrack.estimate import ESTIMATORS
from graphtrack.study import StudyOptions, format_table, run_study
from graphtrack.study.cells import VIEWS


def _list(value: str, allowed, what: str) -> list[str]:
    if value.strip() == "all":
        return list(allowed)
    items = [v.strip() for v in value.split(",") if v.strip()]
    bad = [v for v in items if v not in allowed]
    if bad or not items:
        why = f"unknown {bad[0]!r}" if bad else "empty list"
        raise InputError(f"--{what}: {why} (choose from {', '.join(allowed)}, or all)")
    return list(dict.fromkeys(items))


def study_options_from_args(args) -> StudyOptions:
    """The StudyOptions of a ``compare`` command line (InputError for bad values)."""
    check_run_arguments(args.out, args.max_frames)
    if args.repeats < 1:
        raise InputError("--repeats must be at least 1")
    if args.mono and args.stereo not in (None, "mono"):
        raise InputError(f"--mono and --stereo {args.stereo} contradict each other: give one")
    views = "mono" if args.mono else (args.stereo or StudyOptions.views)
    detection = DetectionOptions(detector=args.detector, weights=args.weights, alpha=args.alpha,
                                 beta=args.beta, markers=not args.no_markers,
                                 shaft_end=not args.no_shaft_end, turn=not args.no_turn).check()
    return StudyOptions(estimators=_list(args.estimators, tuple(ESTIMATORS), "estimators"),
                        observations=_list(args.observations, OBSERVATION_MODELS, "observations"),
                        detection=detection, estimation=estimator_options_from_args(args), seed=args.seed,
                        max_frames=args.max_frames, repeats=args.repeats,
                        views=views, topics=source_from_args(args))


def run(args) -> int:
    options = study_options_from_args(args)
    for sequence in args.sequences:
        outside_recording(args.out, sequence)
    data = run_study(args.sequences, args.out, options, workers=args.workers, ray_address=args.ray,
                     quiet=args.quiet)
    print(format_table(data))  # the table is the command's result: printed also with --quiet
    if not args.quiet:
        print(f"\n{data['ran']} cells computed, {data['reused']} reused; "
              f"wrote {args.out}/table.md, table.csv, runtime.csv, results.csv and "
              f"accumulated_error_<recording>.png (recordings with labels.csv)")
        for n in data["notes"]:
            print(f"note: {n}")
    for rec, key, msg in data["errors"]:
        print(f"graphtrack: cell {rec}/{key} failed: {msg}", file=sys.stderr)
    if data["internal_errors"]:   # a bug (its traceback is in the cell's error.json): exit status 1
        print(f"graphtrack: internal error in {data['internal_errors']} cell(s) (a bug: please report it; "
              "the traceback is in the cell's error.json)", file=sys.stderr)
        return 1
    if data["errors"]:   # the table holds the other cells; a re-run recomputes only the failed ones
        raise InputError(f"{len(data['errors'])} cell(s) failed (listed above and in {args.out}/table.md)")
    return 0


def add_parser(sub):
    p = sub.add_parser("compare", help="compare estimators and observation models over recordings",
                       formatter_class=FORMATTER,
                       description="Run every estimator x observation-model combination on every "
                                   "recording and write the method's Table I (table.md, table.csv), "
                                   "a runtime table and accumulated-error plots. Resumable: finished "
                                   "cells (done.json) are reused.")
    p.add_argument("sequences", nargs="+", metavar="SEQ", help="recording folders")
    p.add_argument("--out", required=True, type=output_path, metavar="DIR", help="study folder")
    p.add_argument("--estimators", default=",".join(StudyOptions().estimators),
                   help="comma-separated estimators, or all")
    p.add_argument("--observations", default="all",
                   help="comma-separated observation models, or all (the six models)")
    p.add_argument("--workers", type=int, default=1, metavar="N", help="local worker processes")
    p.add_argument("--ray", metavar="ADDRESS", default=None,
                   help="run cells as Ray tasks: 'local' (start one here), 'auto' or a cluster address "
                        "(default: local processes)")
    add_detection_arguments(p)
    p.add_argument("--no-markers", action="store_true", help="do not use painted-marker features")
    p.add_argument("--no-shaft-end", action="store_true",
                   help="do not observe where the shaft ends (robot.json's shaft_features[0].end)")
    add_turn_argument(p)
    add_estimator_arguments(p)
    p.add_argument("--repeats", type=int, default=StudyOptions.repeats, metavar="N",
                   help="run each seed-dependent cell (the particle filter; the RANSAC -polar models) "
                        "with seeds SEED..SEED+N-1 and report their mean")
    p.add_argument("--max-frames", type=int, default=StudyOptions.max_frames, metavar="N",
                   help="frames per recording (default: all)")
    p.add_argument("--stereo", choices=VIEWS, default=None,
                   help="the mono / stereo axis: stereo (both images where a recording has a right one), "
                        "mono (left only), both (every cell twice; the mono rows read 'ESTIMATOR (mono)') "
                        f"(default: {StudyOptions.views})")
    p.add_argument("--mono", action="store_true", help="left image only (the same as --stereo mono)")
    p.add_argument("--quiet", action="store_true", help="no progress bar; only the table")
    add_source_arguments(p)
    p.set_defaults(func=run)
