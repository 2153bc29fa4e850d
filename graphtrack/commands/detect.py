"""``graphtrack detect SEQ --detector ... --out DIR``: run a shaft/marker detector alone.

Writes ``detections.csv``, one row per frame (undistorted pixels):

    frame, n_segments, n_edges,
    rho_0, theta_0, x1_0, y1_0, x2_0, y2_0, Ee_0, El_0,    (shaft edge 0)
    rho_1, theta_1, x1_1, y1_1, x2_1, y2_1, Ee_1, El_1,    (shaft edge 1)
    n_markers, markers, ms

where Ee_i / El_i are the sizes of the endpoint set E_e (both endpoints) and
the line set E_l of edge i at --alpha / --beta (the method's 10 px, 0.9),
``markers`` the marker centroids as "x y;x y;...", ``ms`` the detector's
milliseconds. The gate is the shaft predicted by the nominal hand-eye
calibration and the frame's joint readings, as wide as tracking's before its first
estimate (``MAX_GATE_PX``). ``--video`` also writes
``detections.mp4`` (undistorted frames: candidate segments grey, shaft edges
yellow, pixel sets, markers).
"""
from __future__ import annotations

import csv
import dataclasses
import sys
import time

import numpy as np
from tqdm import tqdm

from graphtrack.commands.common import add_source_arguments, output_path, source_from_args
from graphtrack.commands.track import FORMATTER, add_detection_arguments
from graphtrack.detect import detect_raw, make_detector
from graphtrack.detect.draw import draw_detection
from graphtrack.detect.observe import make_observation
from graphtrack.detect.options import DetectionOptions
from graphtrack.detect.pixel_sets import endpoints_set, line_set
from graphtrack.errors import FrameError, InputError
from graphtrack.io.context import TrackingContext
from graphtrack.io.outdir import writable_dir
from graphtrack.io.run_output import DETECT_FILES, check_run_arguments, outside_recording, prepare_run_dir
from graphtrack.io.recording import open_recording
from graphtrack.io.topics import TopicSelection
from graphtrack.io.video import StampedVideoWriter
from graphtrack.robot.features import base_features, shaft_lines
from graphtrack.track import MAX_GATE_PX
from graphtrack.track.runlog import SkipCounter


def _num(x) -> str:
    x = float(x)
    return repr(round(x, 4)) if np.isfinite(x) else "nan"


def _predicted(rec, q, E: np.ndarray, K: np.ndarray):
    """The shaft edges (2, 2) predicted through camera-from-base E and K (None: unknown)."""
    if len(q) != rec.robot.n_joints or not np.all(np.isfinite(q)) or not rec.robot.shaft_features:
        return None
    rho, theta, valid = shaft_lines(base_features(rec.robot, q).transformed(E), K)
    return np.stack([rho, theta], -1) if bool(valid) else None


def _row(index: int, d, shape, alpha: float, beta: float, ms: float) -> list:
    """One detections.csv row of Detection d on an image of ``shape``."""
    row = [index, len(d.segments), len(d.shaft_lines)]
    segs = np.asarray(d.shaft_segments, float).reshape(-1, 4)
    lines = np.asarray(d.shaft_lines, float).reshape(-1, 2)
    for i in range(2):
        if i < len(lines):
            seg = segs[i] if i < len(segs) else np.full(4, np.nan)
            ee = len(endpoints_set(d.heatmap, seg, alpha, beta, shape)) if np.all(np.isfinite(seg)) else 0
            el = len(line_set(d.heatmap, seg, alpha, beta, shape)) if np.all(np.isfinite(seg)) else 0
            row += [_num(lines[i, 0]), _num(lines[i, 1])] + [_num(v) for v in seg] + [ee, el]
        else:
            row += ["nan"] * 6 + [0, 0]
    mk = np.asarray(d.markers, float).reshape(-1, 2)
    return row + [len(mk), ";".join(f"{x:.2f} {y:.2f}" for x, y in mk), _num(ms)]


def start_gate(detector):
    """The detector's association gate widened to tracking's start-up gate (``MAX_GATE_PX``):
    the prediction from the nominal hand-eye is as uncertain as a tracker's first frame."""
    base = getattr(detector, "association", None)
    if base is None or base.max_offset >= MAX_GATE_PX:
        return base
    return dataclasses.replace(base, max_offset=MAX_GATE_PX)


def detect_recording(path, out, options: DetectionOptions = DetectionOptions(), video: bool = False,
                     max_frames: int | None = None, quiet: bool = False,
                     topics: TopicSelection = TopicSelection(), stereo: bool = True,
                     overwrite: bool = False) -> dict:
    """Detect on every frame of a recording; write detections.csv (and detections.mp4).
    Of ``options`` it uses detector, weights, alpha and beta (at full size); ``topics``:
    the arm and bag topics to read (default: detected). A stereo recording (unless
    ``stereo`` is False, ``--mono``) also gets detections_right.csv, the same columns
    for the right images (undistorted right pixels, gated through right_T_left . E_0).
    ``out`` holding another run's files (DETECT_FILES) is refused unless ``overwrite``."""
    check_run_arguments(out, max_frames)
    rec = open_recording(path, topics=topics)
    ctx = TrackingContext(rec.robot, rec.calibration.left, rec.handeye)
    out = writable_dir(prepare_run_dir(out, overwrite, DETECT_FILES))
    right_csv = None
    if stereo and rec.stereo:
        right_csv = (out / "detections_right.csv").open("w", newline="")
        E_right = rec.calibration.right_T_left @ rec.handeye
    detector, alpha, beta = options.detector, options.alpha, options.beta
    det = make_detector(detector, **options.detector_keywords())
    gate = start_gate(det)
    writer = None
    if video:
        writer = StampedVideoWriter(out / "detections.mp4")
    header = ["frame", "n_segments", "n_edges"]
    for i in range(2):
        header += [f"{k}_{i}" for k in ("rho", "theta", "x1", "y1", "x2", "y2", "Ee", "El")]
    header += ["n_markers", "markers", "ms"]
    total = len(rec) if max_frames is None else min(len(rec), max_frames)
    n = 0
    skipped = SkipCounter()
    ms_all = []
    with (out / "detections.csv").open("w", newline="") as f, \
            tqdm(total=total, desc=f"detect {detector}", unit="frame", file=sys.stderr, disable=quiet) as bar:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(header)
        wr = None if right_csv is None else csv.writer(right_csv, lineterminator="\n")
        if wr is not None:
            wr.writerow(header)
        for item in rec.frames():
            if max_frames is not None and n >= max_frames:
                break
            n += 1
            bar.update(1)
            if isinstance(item, FrameError) or item.image is None:
                skipped.skip(item if isinstance(item, FrameError) else FrameError(item.index, "no_image", "no image"),
                             quiet=True)
                continue
            t = time.perf_counter()
            d = detect_raw(det, item.image, ctx.camera, _predicted(rec, item.q, ctx.handeye, ctx.camera.K), gate)
            ms = d.ms if d.ms else 1e3 * (time.perf_counter() - t)
            ms_all.append(ms)
            w.writerow(_row(item.index, d, item.image.shape[:2], alpha, beta, ms))
            f.flush()
            if wr is not None and item.image_right is not None:
                right = rec.calibration.right
                t = time.perf_counter()
                d_r = detect_raw(det, item.image_right, right, _predicted(rec, item.q, E_right, right.K), gate)
                wr.writerow(_row(item.index, d_r, item.image_right.shape[:2], alpha, beta,
                                 d_r.ms if d_r.ms else 1e3 * (time.perf_counter() - t)))
            if writer is not None:
                obs = make_observation(d, "line-intensities", alpha=alpha, beta=beta, use_markers=True)
                writer.write(draw_detection(ctx.camera.undistort(item.image), d, obs), item.stamp)
    if writer is not None:
        writer.close()
    if right_csv is not None:
        right_csv.close()
    return {"frames": n, "frames_skipped": sum(skipped.values()), "skipped_reasons": dict(skipped),
            "right": right_csv is not None,
            # the first reason met holds the first skipped frame's message
            "first_skip": next(iter(skipped.examples.values()), ""),
            "ms_median": float(np.median(ms_all)) if ms_all else float("nan")}


def run(args) -> int:
    check_run_arguments(args.out, args.max_frames)
    outside_recording(args.out, args.sequence)
    options = DetectionOptions(detector=args.detector, weights=args.weights, alpha=args.alpha, beta=args.beta)
    res = detect_recording(args.sequence, args.out, options.check(), args.video, args.max_frames, args.quiet,
                           topics=source_from_args(args), stereo=not args.mono, overwrite=args.overwrite)
    counts = ", ".join(f"{k}: {v}" for k, v in sorted(res["skipped_reasons"].items()))
    if res["frames"] == 0:
        raise InputError(f"{args.sequence}: the recording has no frames; {args.out}/detections.csv holds only "
                         "its header")
    if res["frames"] == res["frames_skipped"]:   # never exit 0 with nothing detected
        raise InputError(f"{args.sequence}: no frame could be detected on: {res['frames_skipped']} of "
                         f"{res['frames']} frames skipped ({counts}); first: {res['first_skip']}; "
                         f"{args.out}/detections.csv holds only its header")
    if not args.quiet:
        why = f": {counts}; first: {res['first_skip']}" if res["frames_skipped"] else ""
        print(f"{res['frames']} frames ({res['frames_skipped']} skipped{why}), detector median "
              f"{res['ms_median']:.1f} ms; wrote {args.out}/detections.csv"
              + (", detections_right.csv" if res["right"] else "") + (", detections.mp4" if args.video else ""))
    return 0


def add_parser(sub):
    p = sub.add_parser("detect", help="run a shaft/marker detector over a recording", formatter_class=FORMATTER,
                       description="Detect the shaft edges, pixel sets and markers in every frame and "
                                   "write detections.csv (and --video detections.mp4).")
    p.add_argument("sequence", metavar="SEQ", help="recording folder")
    p.add_argument("--out", required=True, type=output_path, metavar="DIR", help="output folder")
    add_detection_arguments(p)
    p.add_argument("--video", action="store_true", help="also write detections.mp4")
    p.add_argument("--max-frames", type=int, default=None, metavar="N", help="detect on at most N frames (default: all)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--mono", action="store_true",
                   help="left images only (default: also detections_right.csv when the recording has right images)")
    add_source_arguments(p)
    p.add_argument("--overwrite", action="store_true",
                   help="replace another detect run's files in --out (refused otherwise)")
    p.set_defaults(func=run)
