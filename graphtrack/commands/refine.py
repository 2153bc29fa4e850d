"""``graphtrack refine SEQ --observation ... --out DIR``: offline batch refinement of a recording.

The same as ``graphtrack track --estimator batch``: every frame's E_t is
re-estimated with all frames' observations (Levenberg-Marquardt over the whole
recording) and the refined trajectory replaces the streamed one.
"""
from __future__ import annotations

from graphtrack.commands.track import FORMATTER, add_tracking_arguments
from graphtrack.commands.track import run as track_run


def run(args) -> int:
    args.estimator = "batch"
    return track_run(args)


def add_parser(sub):
    p = sub.add_parser("refine", help="offline batch refinement of a whole recording", formatter_class=FORMATTER,
                       description="Refine the lumped error E over a whole recording offline (the "
                                   "batch estimator) and write trajectory.csv, trajectory.tum and "
                                   "metrics.json.")
    add_tracking_arguments(p, estimators=("batch",), default_estimator="batch", smoother_options=False)
    p.set_defaults(func=run)
