"""``graphtrack track SEQ --estimator ... --out DIR``: track one recording."""
from __future__ import annotations

import json

from graphtrack.commands.common import add_source_arguments, add_threads_argument, source_from_args
from graphtrack.detect.base import OBSERVATION_MODELS
from graphtrack.estimate import ESTIMATORS

DETECTORS = ("canny", "learned", "sold2")


def add_tracking_arguments(p, estimators=tuple(ESTIMATORS), default_estimator="kinematics"):
    """Arguments shared by ``track`` and ``refine``."""
    p.add_argument("sequence", metavar="SEQ", help="recording folder (bag or plain-folder form)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--estimator", choices=estimators, default=default_estimator)
    p.add_argument("--observation", choices=OBSERVATION_MODELS, default="line-intensities",
                   help="observation model of the method (default: line-intensities)")
    p.add_argument("--detector", choices=DETECTORS, default="learned",
                   help="shaft/marker detector (default: learned, the shipped CPU line network)")
    p.add_argument("--detect-scale", type=float, default=None, metavar="S",
                   help="detect on the undistorted image scaled by S (default: auto, at most 960 px wide)")
    p.add_argument("--weights", metavar="FILE", help="weights for --detector learned/sold2")
    p.add_argument("--no-markers", action="store_true", help="do not use painted-marker features")
    p.add_argument("--particles", type=int, default=1000, help="particle filter: number of particles")
    p.add_argument("--lag", type=float, default=1.0, metavar="SECONDS", help="smoother: fixed lag")
    p.add_argument("--smoother", choices=("isam2", "batch"), default="isam2",
                   help="smoother: gtsam IncrementalFixedLagSmoother or BatchFixedLagSmoother")
    p.add_argument("--no-edge-bias", action="store_true",
                   help="smoother/batch: no edge-bias state (for edges or lines known to be unbiased)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--alpha", type=float, default=10.0, help="pixel-set radius alpha (px)")
    p.add_argument("--beta", type=float, default=0.9, help="pixel-set heatmap threshold beta")
    p.add_argument("--tip-feature", metavar="NAME",
                   help="evaluate this robot.json point feature as the tool tip (default: tool_tip)")
    p.add_argument("--max-frames", type=int, default=None, metavar="N")
    p.add_argument("--video", action="store_true", help="also write overlay.mp4")
    p.add_argument("--quiet", action="store_true", help="no progress bar or warnings")
    add_threads_argument(p)
    add_source_arguments(p)
    p.add_argument("--overwrite", action="store_true",
                   help="replace another run's files in --out (refused otherwise)")


def options_from_args(args):
    from graphtrack.errors import InputError
    from graphtrack.track import TrackOptions

    if args.particles <= 0:
        raise InputError("--particles must be positive")
    if args.lag <= 0:
        raise InputError("--lag must be positive")
    if getattr(args, "max_frames", None) is not None and args.max_frames < 1:
        raise InputError("--max-frames must be at least 1")
    detect_scale = getattr(args, "detect_scale", None)
    if detect_scale is not None and not 0.05 <= detect_scale <= 1.0:
        raise InputError("--detect-scale must be in [0.05, 1]")
    est_opts = {}
    if args.estimator == "pf":
        est_opts = {"particles": args.particles, "seed": args.seed}
    elif args.estimator == "smoother":
        est_opts = {"lag": args.lag, "smoother": args.smoother}
    if args.estimator in ("smoother", "batch") and getattr(args, "no_edge_bias", False):
        est_opts["edge_bias"] = False
    det_opts = {"weights": args.weights} if args.weights else {}
    return TrackOptions(estimator=args.estimator, observation=args.observation, detector=args.detector,
                        markers=not args.no_markers, estimator_options=est_opts, detector_options=det_opts,
                        alpha=args.alpha, beta=args.beta, seed=args.seed, detect_scale=detect_scale,
                        tip_feature=getattr(args, "tip_feature", None))


def run(args) -> int:
    from graphtrack.io.run_output import prepare_run_dir, require_tracked
    from graphtrack.track import track

    options = options_from_args(args)
    prepare_run_dir(args.out, overwrite=args.overwrite)
    result = track(args.sequence, args.out, options, video=args.video,
                   progress=not args.quiet, max_frames=args.max_frames, quiet=args.quiet,
                   topics=source_from_args(args))
    require_tracked(result, args.out)   # no tracked frame: exit status 2, never 0
    if not args.quiet:
        keys = ("frames_tracked", "frames_skipped", "tip_error_px", "tip_error_percent_diagonal", "fps")
        print(json.dumps({k: result[k] for k in keys if k in result}, indent=2))
        video = ", overlay.mp4" if args.video else ""
        print(f"wrote {args.out}/trajectory.csv, trajectory.tum, metrics.json{video}")
    return 0


def add_parser(sub):
    p = sub.add_parser("track", help="track the lumped error E over one recording",
                       description="Track the lumped-error transform E over a recording and write "
                                   "trajectory.csv, trajectory.tum and metrics.json.")
    add_tracking_arguments(p)
    p.set_defaults(func=run)
