"""``graphtrack demo``: the whole method in about a minute on a laptop, no data needed.

Simulates two short recordings into the cache (once: a structured bench scene
and a tissue scene), runs the kinematics baseline, the particle filter and
the fixed-lag smoother with the method's default observation model
(line-intensities; the learned detector when its weights are installed,
Canny otherwise) as a small comparison study, prints the tip-error table and
names the accumulated-error plots and the overlay video (smoother, tissue)
it wrote.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from graphtrack.commands.common import output_path
from graphtrack.commands.track import FORMATTER
from graphtrack.detect.options import DetectionOptions
from graphtrack.errors import InputError
from graphtrack.estimate.options import EstimatorOptions
from graphtrack.sim.simulate import cached_recording
from graphtrack.study import StudyOptions, format_table, run_study

#: Demo defaults: short recordings at the camera's half resolution.
FRAMES = 150
SIZE = (540, 960)
SEED = 0


def default_detector() -> tuple[str, str | None]:
    """('learned', None) when the shipped learned-detector weights exist, else ('canny', None)."""
    try:  # lazy: learned.py loads torch (seconds), and the CLI imports every command to build its parser
        from graphtrack.detect.learned import DEFAULT_WEIGHTS
    except ImportError:
        return "canny", None
    return ("learned", None) if Path(DEFAULT_WEIGHTS).is_file() else ("canny", None)


def run_demo(out: str | Path = "graphtrack-demo", frames: int = FRAMES, size=SIZE,
             particles: int = EstimatorOptions.particles, quiet: bool = False, detector: str | None = None) -> dict:
    if frames <= 0:
        raise InputError("--frames must be positive")
    out = Path(out)
    say = (lambda *a: None) if quiet else (lambda *a: print(*a, file=sys.stderr))
    if detector is None:
        detector, _ = default_detector()
        if detector == "canny":
            say("graphtrack demo: note: the learned detector's weights are not installed "
                "(graphtrack/data/learned_detector.pt): the demo uses the canny detector")
    say(f"graphtrack demo: simulating {frames}-frame recordings ({size[0]}x{size[1]}, height x width) into the cache "
        f"(first run only)")
    size = tuple(size)
    recs = []
    for scene in ("structured", "tissue"):
        recs.append(str(cached_recording(scene, frames=frames, seed=SEED, size=size, progress=not quiet)))
    options = StudyOptions(estimators=["kinematics", "pf", "smoother"], observations=["line-intensities"],
                           detection=DetectionOptions(detector=detector),
                           estimation=EstimatorOptions(particles=particles, seed=SEED), seed=SEED)
    say(f"graphtrack demo: kinematics, particle filter ({particles} particles) and fixed-lag smoother, "
        f"observation line-intensities, detector {detector}")
    tissue = recs[1]

    def wants_video(cell) -> bool:  # one overlay video: the smoother on the tissue recording
        return cell.estimator == "smoother" and cell.path == str(Path(tissue).resolve())

    data = run_study(recs, out, options, workers=1, quiet=quiet, video=wants_video,
                     names=["structured", "tissue"])
    videos = [Path(c.out) / "overlay.mp4" for c in data["cells"] if c.video]
    data["video"] = videos[0] if videos and videos[0].is_file() else None
    data["table_text"] = format_table(data)
    return data


def run(args) -> int:
    data = run_demo(args.out, frames=args.frames, quiet=args.quiet)
    out = Path(args.out)
    print()
    print("2-D tool-tip error, % of the image diagonal: mean (std)")
    print(data["table_text"])
    print()
    for rec, key, msg in data["errors"]:   # the demo makes its own input: a failure is a bug (exit 1 below)
        print(f"graphtrack: cell {rec}/{key} failed: {msg}", file=sys.stderr)
    plots = sorted(out.glob("accumulated_error_*.png"))
    print(f"table:  {out / 'table.md'}")
    for p in plots:
        print(f"plot:   {p}")
    if data["video"] is not None:
        print(f"video:  {data['video']}")
    print(f"runs:   {out / 'runs'}/<recording>/<estimator>-<observation>/ "
          f"(trajectory.csv, trajectory.tum, metrics.json)")
    return 1 if data["errors"] else 0


def add_parser(sub):
    p = sub.add_parser("demo", help="simulate two short recordings and compare the estimators on them",
                       formatter_class=FORMATTER,
                       description="Simulate a structured and a tissue recording (cached), track them "
                                   "with the kinematics baseline, the particle filter and the smoother, "
                                   "and write the error table, plots and an overlay video.")
    p.add_argument("--out", default="graphtrack-demo", type=output_path, metavar="DIR",
                   help="output folder")
    p.add_argument("--frames", type=int, default=FRAMES, help=argparse.SUPPRESS)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)
