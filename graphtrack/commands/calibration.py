"""``graphtrack calibration --out SEQ --ros LEFT.yaml [RIGHT.yaml] --dvrk-registration PSMx.json``:
camera_calibration.yaml and handeye.yaml from the files the dVRK's calibration tools write.

--ros takes ROS camera_calibration's camera_info YAMLs (ost.yaml, or left.yaml and
right.yaml of a stereo calibration: the left camera's first); --dvrk-registration takes
dvrk_camera_registration's PSMx-registration-open-cv.json (the PSM base in the camera's
frame). The registration was measured through the rectified left image: with --ros it is
turned into the raw left camera's frame, or kept in the rectified one with --rectified
(a recording of the rectified image topics). Lengths are read in --length-unit (ROS and
the dVRK: metres) and written as the recording format wants them (mm). Each file written
is checked by loading it back.
"""
from __future__ import annotations

import sys
from pathlib import Path

from graphtrack.commands.common import HelpFormatter, output_path
from graphtrack.errors import InputError
from graphtrack.geometry.camera import load_calibration, save_calibration
from graphtrack.io import calibration_import as ci
from graphtrack.io.handeye import load_handeye, save_handeye
from graphtrack.io.topics import ARMS


def _targets(args) -> dict[str, Path]:
    out = Path(args.out)
    names = (["camera_calibration.yaml"] if args.ros else []) + (["handeye.yaml"] if args.dvrk_registration else [])
    if not names:
        raise InputError("nothing to write: give --ros (camera_calibration.yaml) and/or --dvrk-registration "
                         "(handeye.yaml)")
    targets = {n: out / n for n in names}
    for p in targets.values():
        if p.exists() and not args.overwrite:
            raise InputError(f"{p}: already exists (pass --overwrite to replace it)")
    return targets


def _write_all(files: dict[Path, tuple], unit: str) -> None:
    """For each path: (save, check, source). Every file is saved beside its path and
    checked by the loader the tracker uses before any replaces its path: one the tracker
    would refuse raises its error (naming the path and the ``source`` it came from) and
    nothing is written."""
    staged = {p: p.with_name(p.name + ".partial") for p in files}
    try:
        for p, (save, check, source) in files.items():
            try:
                p.parent.mkdir(parents=True, exist_ok=True)
                save(staged[p])
            except OSError as e:
                raise InputError(f"{p}: cannot write ({e.strerror or e})") from None
            try:
                check(staged[p])
            except InputError as e:
                raise InputError(f"{str(e).replace(str(staged[p]), str(p))} (written from {source}, its lengths "
                                 f"read in {unit}: see --length-unit)") from None
        for p, tmp in staged.items():
            tmp.replace(p)
    finally:
        for tmp in staged.values():
            tmp.unlink(missing_ok=True)


def run(args) -> int:
    if args.ros and len(args.ros) > 2:
        raise InputError(f"--ros takes one file (mono) or two (left, right), got {len(args.ros)}")
    if args.rectified and not args.ros:
        raise InputError("--rectified describes the rectified cameras of --ros: give --ros")
    targets = _targets(args)
    cams = [ci.read_ros_camera(p) for p in args.ros or []]
    calib = ci.calibration_from_ros(*cams, rectified=args.rectified, unit=args.length_unit) if cams else None
    handeye = arm = None
    if args.dvrk_registration:
        arm = args.arm or ci.arm_of(args.dvrk_registration)
        if arm is None:
            raise InputError(f"{args.dvrk_registration}: its name does not start with PSM1, PSM2 or PSM3: "
                             "name the arm with --arm")
        handeye = ci.read_dvrk_registration(args.dvrk_registration, args.length_unit)
        if cams and not args.rectified:
            handeye = ci.handeye_to_raw(handeye, cams[0])
    files = {}
    if calib is not None:
        files[targets["camera_calibration.yaml"]] = (lambda p: save_calibration(p, calib), load_calibration,
                                                     " and ".join(args.ros))
    if handeye is not None:
        files[targets["handeye.yaml"]] = (lambda p: save_handeye(p, handeye, arm), lambda p: load_handeye(p, arm),
                                          args.dvrk_registration)
    _write_all(files, args.length_unit)
    if calib is not None:
        print(f"wrote {targets['camera_calibration.yaml']}: {'stereo' if calib.stereo else 'mono'}, "
              f"{calib.left.width}x{calib.left.height}{', rectified' if args.rectified else ''}", file=sys.stderr)
    if handeye is not None:
        frame = "rectified left" if args.rectified or not cams else "left"
        print(f"wrote {targets['handeye.yaml']}: {arm} base in the {frame} camera's frame", file=sys.stderr)
        if not cams:
            print("graphtrack: note: without --ros the registration stays in the rectified left camera's frame; "
                  "for a recording of raw images pass the left camera's YAML with --ros", file=sys.stderr)
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("calibration", formatter_class=HelpFormatter,
                       help="write camera_calibration.yaml and handeye.yaml from ROS and dVRK calibration files",
                       description=__doc__.split("\n\n", 1)[1])
    p.add_argument("--out", required=True, type=output_path, metavar="SEQ",
                   help="recording folder to write camera_calibration.yaml and handeye.yaml into")
    p.add_argument("--ros", nargs="+", metavar="YAML", default=None,
                   help="ROS camera_info YAML: one (mono) or the left and the right camera's (stereo) (default: no camera_calibration.yaml)")
    p.add_argument("--rectified", action="store_true",
                   help="the recording holds the rectified images: describe the rectified cameras")
    p.add_argument("--dvrk-registration", metavar="JSON", default=None,
                   help="dvrk_camera_registration's PSMx-registration-open-cv.json (default: no handeye.yaml)")
    p.add_argument("--arm", choices=ARMS, default=None,
                   help="the arm of --dvrk-registration (default: from its file name)")
    p.add_argument("--length-unit", choices=tuple(ci.UNITS_M), default="m",
                   help="the unit of the calibrations' lengths (the stereo baseline, the registration)")
    p.add_argument("--overwrite", action="store_true", help="replace existing files in --out")
    p.set_defaults(func=run)
