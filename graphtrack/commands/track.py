"""``graphtrack track SEQ --estimator ... --out DIR``: track one recording.

The command line builds a :class:`graphtrack.track.TrackOptions` (with its
:class:`~graphtrack.detect.options.DetectionOptions` and
:class:`~graphtrack.estimate.options.EstimatorOptions`); every default shown by
``--help`` is the dataclasses' own.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

from graphtrack.commands.common import (HelpFormatter, add_source_arguments, add_threads_argument, mm_deg,
                                        output_path, source_from_args)
from graphtrack.detect import available_detectors
from graphtrack.detect.base import OBSERVATION_MODELS
from graphtrack.detect.options import DetectionOptions
from graphtrack.estimate import ESTIMATORS
from graphtrack.estimate.options import PRIOR_SIGMA_B, PRIOR_SIGMA_W, SMOOTHER_KINDS, EstimatorOptions
from graphtrack.errors import InputError
from graphtrack.track import TrackOptions, track
from graphtrack.track.runlog import warn

FORMATTER = HelpFormatter


def add_detection_arguments(p, weights: bool = True) -> None:
    """--detector, --weights, --alpha, --beta (the DetectionOptions a command exposes)."""
    p.add_argument("--detector", choices=available_detectors(), default=DetectionOptions.detector,
                   help="shaft/marker detector (learned: the shipped CPU line network)")
    if weights:
        p.add_argument("--weights", metavar="FILE", default=DetectionOptions.weights,
                       help="weights for --detector learned/sold2 (default: the shipped ones)")
    p.add_argument("--alpha", type=float, default=DetectionOptions.alpha, help="pixel-set radius alpha (px)")
    p.add_argument("--beta", type=float, default=DetectionOptions.beta, help="pixel-set heatmap threshold beta")


def add_turn_argument(p) -> None:
    """--no-turn (DetectionOptions.turn)."""
    p.add_argument("--no-turn", action="store_true",
                   help="--detector learned: never turn the net's input (it is turned by 45 deg where the "
                        "predicted shaft lies near an image axis, which the shipped net does not see)")


def add_estimator_arguments(p, particles: bool = True, smoother: bool = True) -> None:
    """--particles (pf), --lag and --smoother (fixed-lag smoother), --seed; the options a
    command does not expose keep EstimatorOptions' defaults in ``args`` (and --no-edge-bias,
    which only ``track`` adds, is False), so :func:`estimator_options_from_args` reads them all."""
    d = EstimatorOptions()
    p.set_defaults(no_edge_bias=False)
    if not particles:
        p.set_defaults(particles=d.particles)
    if not smoother:
        p.set_defaults(lag=d.lag, smoother=d.smoother)
    if not (particles or smoother):
        p.set_defaults(no_search=False)
    if particles:
        p.add_argument("--particles", type=int, default=EstimatorOptions.particles,
                       help="particle filter: number of particles")
    if smoother:
        p.add_argument("--lag", type=float, default=EstimatorOptions.lag, metavar="SECONDS",
                       help="smoother: fixed lag")
        p.add_argument("--smoother", choices=SMOOTHER_KINDS, default=EstimatorOptions.smoother,
                       help="smoother: gtsam IncrementalFixedLagSmoother (isam2) or BatchFixedLagSmoother")
    if particles or smoother:
        p.add_argument("--no-search", action="store_true",
                       help="pf/smoother: no global start-up search, divergence monitor or re-initialisation "
                            "(the local start-up, for comparisons)")
    p.add_argument("--handeye-sigma", metavar="MM,DEG", default=None,
                   help="how far handeye.yaml may be off, per axis (1 sigma) of its translation and rotation: "
                        "the hand-eye prior and the start-up search's extent; widen it for a rough calibration "
                        f"(default: {PRIOR_SIGMA_B * 1e3:g},{math.degrees(PRIOR_SIGMA_W):.0f}, tracks "
                        "errors up to about 10 mm / 5 deg; docs/decisions/handeye-sigma.md)")
    p.add_argument("--seed", type=int, default=TrackOptions.seed,
                   help="seed of the RANSAC observation models and the particle filter")


def add_tracking_arguments(p, estimators=tuple(ESTIMATORS), default_estimator=TrackOptions.estimator,
                           smoother_options: bool = True) -> None:
    """Arguments shared by ``track`` and ``refine`` (refine: the batch only, no pf/smoother options)."""
    p.add_argument("sequence", metavar="SEQ", help="recording folder (bag or plain-folder form)")
    p.add_argument("--out", required=True, type=output_path, metavar="DIR", help="output folder")
    p.add_argument("--estimator", choices=estimators, default=default_estimator, help="estimator of E")
    p.add_argument("--observation", choices=OBSERVATION_MODELS, default=TrackOptions.observation,
                   help="observation model of the method")
    add_detection_arguments(p)
    p.add_argument("--detect-scale", type=float, default=DetectionOptions.scale, metavar="S",
                   help="detect on the undistorted image scaled by S (default: auto, at most 960 px wide)")
    p.add_argument("--no-markers", action="store_true", help="do not use painted-marker features")
    p.add_argument("--no-shaft-end", action="store_true",
                   help="do not observe where the shaft ends (robot.json's shaft_features[0].end)")
    add_turn_argument(p)
    add_mono_argument(p)
    add_estimator_arguments(p, particles=smoother_options, smoother=smoother_options)
    p.add_argument("--no-edge-bias", action="store_true",
                   help="smoother/batch: no edge-bias state (for edges or lines known to be unbiased)")
    p.add_argument("--tip-feature", metavar="NAME", default=TrackOptions.tip_feature,
                   help="evaluate this robot.json point feature as the tool tip (default: robot.json's tool_tip)")
    p.add_argument("--max-frames", type=int, default=None, metavar="N", help="track at most N frames (default: all)")
    p.add_argument("--video", action="store_true", help="also write overlay.mp4")
    p.add_argument("--quiet", action="store_true", help="no progress bar or warnings")
    add_threads_argument(p)
    add_source_arguments(p)
    p.add_argument("--overwrite", action="store_true",
                   help="replace another run's files in --out (refused otherwise)")


def add_mono_argument(p) -> None:
    p.add_argument("--mono", action="store_true",
                   help="left image only (default: both images whenever the recording has a right one)")


def estimator_options_from_args(args) -> EstimatorOptions:
    """The EstimatorOptions of a command line built with :func:`add_estimator_arguments`
    (InputError for bad values; the seed and the ranges: :meth:`EstimatorOptions.check`)."""
    if not math.isfinite(args.lag):
        raise InputError(f"--lag must be a finite number of seconds, got {args.lag!r}")
    return EstimatorOptions(particles=args.particles, seed=args.seed, lag=args.lag, smoother=args.smoother,
                            edge_bias=not args.no_edge_bias, search=not args.no_search,
                            handeye_sigma=mm_deg(args.handeye_sigma, "--handeye-sigma")).check()


def options_from_args(args) -> TrackOptions:
    """The TrackOptions of a ``track`` / ``refine`` command line (InputError for bad values)."""
    detection = DetectionOptions(detector=args.detector, weights=args.weights, alpha=args.alpha, beta=args.beta,
                                 markers=not args.no_markers, scale=args.detect_scale,
                                 shaft_end=not args.no_shaft_end,
                                 turn=not args.no_turn).check()
    return TrackOptions(estimator=args.estimator, observation=args.observation, detection=detection,
                        estimation=estimator_options_from_args(args), seed=args.seed,
                        tip_feature=args.tip_feature, stereo=not args.mono)


#: option (argparse dest) -> the estimators it applies to
ESTIMATOR_ONLY = {"particles": ("pf",), "lag": ("smoother",), "smoother": ("smoother",),
                  "no_search": ("pf", "smoother"), "no_edge_bias": ("smoother", "batch"),
                  "handeye_sigma": ("pf", "smoother", "batch")}


def unused_options(args) -> list[str]:
    """The options given on this command line (other than their defaults) that the chosen
    estimator does not take: one warning line each, instead of silence."""
    d = EstimatorOptions()
    defaults = {"particles": d.particles, "lag": d.lag, "smoother": d.smoother, "no_search": False,
                "no_edge_bias": False, "handeye_sigma": None}
    return [f"warning: --{k.replace('_', '-')} applies to {' and '.join(e)}, not to {args.estimator}: ignored"
            for k, e in ESTIMATOR_ONLY.items()
            if hasattr(args, k) and getattr(args, k) != defaults[k] and args.estimator not in e]


def run(args) -> int:
    options = options_from_args(args)
    for line in unused_options(args):
        warn(line, args.quiet)
    result = track(args.sequence, args.out, options, video=args.video,   # InputError: exit status 2
                   progress=not args.quiet, max_frames=args.max_frames, quiet=args.quiet,
                   topics=source_from_args(args), overwrite=args.overwrite)
    if not args.quiet:
        keys = ("frames_tracked", "frames_skipped", "tip_error_px", "tip_error_percent_diagonal", "fps",
                "estimator_report")
        print(json.dumps({k: result[k] for k in keys if k in result}, indent=2))
        for line in scored_lines(result):
            print(line)
        written = ["metrics.json"] + (["truth_errors.csv"] if (Path(args.out) / "truth_errors.csv").is_file() else [])
        video = ", overlay.mp4" if args.video else ""
        print(f"wrote {args.out}/trajectory.csv, trajectory.tum, {', '.join(written)}{video}")
    return 0


def scored_lines(result: dict) -> list[str]:
    """One line each for the figures metrics.json holds beyond the left image's labels: the
    right image's tip error, the 3-D error against the triangulated labels, and against truth.csv
    with its split along the viewing ray (stereo's gain is in depth)."""
    def mean(key):
        v = (result.get(key) or {}).get("mean")
        return v if isinstance(v, (int, float)) and math.isfinite(v) else None

    lines = []
    if mean("tip_error_right_px") is not None:
        lines.append(f"right image: tip error {mean('tip_error_right_px'):.2f} px mean "
                     f"({result.get('frames_scored_right', 0)} frames with labels_right.csv)")
    if mean("tip_error_3d_labels_mm") is not None:
        per_px = result.get("labels_3d_mm_per_px")
        note = (f" (one pixel of disparity between the two labels is {per_px:.1f} mm of depth here)"
                if isinstance(per_px, float) and math.isfinite(per_px) else "")
        lines.append(f"3-D tip error against the triangulated labels: {mean('tip_error_3d_labels_mm'):.3f} mm mean{note}")
    if mean("tip_error_3d_mm") is not None:
        split = ""
        if mean("tip_error_3d_depth_mm") is not None:
            split = (f" ({mean('tip_error_3d_depth_mm'):.3f} along the viewing ray, "
                     f"{mean('tip_error_3d_lateral_mm'):.3f} across it)")
        lines.append(f"3-D tip error against truth.csv: {mean('tip_error_3d_mm'):.3f} mm mean{split}")
    return lines


def add_parser(sub):
    p = sub.add_parser("track", help="track the lumped error E over one recording", formatter_class=FORMATTER,
                       description="Track the lumped-error transform E over a recording and write "
                                   "trajectory.csv, trajectory.tum and metrics.json.")
    add_tracking_arguments(p)
    p.set_defaults(func=run)
