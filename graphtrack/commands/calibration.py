"""``graphtrack calibration --out SEQ --ros LEFT.yaml [RIGHT.yaml] --dvrk-registration PSMx.json``:
camera_calibration.yaml and handeye.yaml from the files the dVRK's calibration tools write.

--ros takes ROS camera_calibration's camera_info YAMLs (ost.yaml, or left.yaml and
right.yaml of a stereo calibration: the left camera's first), --bag the same from a
bag's camera_info messages; --dvrk-registration takes dvrk_camera_registration's
PSMx-registration-open-cv.json (the PSM base in the camera's frame). The registration
was measured through the rectified left image: with the cameras (--ros or --bag) it is
turned into the raw left camera's frame, or kept in the rectified one with --rectified (a
recording of the rectified image topics). Lengths are read in --length-unit (ROS and the
dVRK: metres) and written as the recording format wants them (mm). Nothing is written
unless every file passes the checks tracking makes when it reads them.
"""
from __future__ import annotations

import contextlib
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
    names = ((["camera_calibration.yaml"] if args.ros or args.bag else [])
             + (["handeye.yaml"] if args.dvrk_registration else []))
    if not names:
        raise InputError("nothing to write: give --ros or --bag (camera_calibration.yaml) and/or "
                         "--dvrk-registration (handeye.yaml)")
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: not a folder (--out names the recording folder the files go into)")
    targets = {n: out / n for n in names}
    for p in targets.values():
        if p.is_dir():
            raise InputError(f"{p}: is a folder")
        if p.exists() and not args.overwrite:
            raise InputError(f"{p}: already exists (pass --overwrite to replace it)")
    return targets


#: loader errors about lengths, which a wrong --length-unit causes
_LENGTH_KEYS = ("'T'", "_tvec'")


def _write_all(files: dict[Path, tuple], unit: str) -> None:
    """For each path: (save, check, source). Every file is saved beside its path and
    checked by the loader the tracker uses before any replaces its path: one the tracker
    would refuse raises its error (naming the path and the ``source`` it came from) and
    nothing is written (a folder made for them is removed again)."""
    staged = {p: p.with_name(p.name + ".partial") for p in files}
    made = [d for d in {p.parent for p in files} if not d.exists()]
    done = False
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
                msg = str(e).replace(str(staged[p]), str(p))
                hint = f", its lengths read in {unit}: see --length-unit" if any(k in msg for k in _LENGTH_KEYS) else ""
                raise InputError(f"{msg} (written from {source}{hint})") from None
        for p, tmp in staged.items():
            try:
                tmp.replace(p)
            except OSError as e:
                raise InputError(f"{p}: cannot write ({e.strerror or e})") from None
        done = True
    finally:
        for tmp in staged.values():
            with contextlib.suppress(OSError):
                tmp.unlink(missing_ok=True)
        for d in made if not done else []:
            with contextlib.suppress(OSError):
                d.rmdir()   # only if empty


def _registration(args, cams):
    """(arm, camera-from-base) of --dvrk-registration, in the raw left camera's frame when
    the cameras are given and not --rectified."""
    path = args.dvrk_registration
    named = ci.arm_of(path)
    if args.arm and named and args.arm != named:
        raise InputError(f"{path}: the registration of {named}, but --arm {args.arm}")
    arm = args.arm or named
    if arm is None:
        raise InputError(f"{path}: its name does not start with PSM1, PSM2 or PSM3: name the arm with --arm")
    reg = ci.read_dvrk_registration(path, args.length_unit)
    if "right" in reg.reference_frame.lower():
        print(f"graphtrack: warning: {path}: its reference-frame is {reg.reference_frame!r}: registered through "
              "the right camera? handeye.yaml is the left camera's", file=sys.stderr)
    return arm, (ci.handeye_to_raw(reg.transform, cams[0]) if cams and not args.rectified else reg.transform)


def run(args) -> int:
    for name, value in (("--ros", args.ros), ("--camera-info-topic", args.camera_info_topic)):
        if value and len(value) > 2:
            raise InputError(f"{name} takes one (mono) or two (left, right), got {len(value)}")
    if args.ros and args.bag:
        raise InputError("give the cameras once: --ros YAMLs or --bag's camera_info, not both")
    if args.camera_info_topic and not args.bag:
        raise InputError("--camera-info-topic names topics of --bag: give --bag")
    if args.rectified and not (args.ros or args.bag):
        raise InputError("--rectified describes the rectified cameras of --ros or --bag: give one")
    targets = _targets(args)
    cams, topics = (([ci.read_ros_camera(p) for p in args.ros], args.ros) if args.ros else
                    ci.read_bag_cameras(args.bag, args.camera_info_topic) if args.bag else ([], []))
    calib = ci.calibration_from_ros(*cams, rectified=args.rectified, unit=args.length_unit) if cams else None
    arm, handeye = _registration(args, cams) if args.dvrk_registration else (None, None)
    files = {}
    if calib is not None:
        files[targets["camera_calibration.yaml"]] = (lambda p: save_calibration(p, calib), load_calibration,
                                                     " and ".join(map(str, topics)))
    if handeye is not None:
        files[targets["handeye.yaml"]] = (lambda p: save_handeye(p, handeye, arm), lambda p: load_handeye(p, arm),
                                          args.dvrk_registration)
    _write_all(files, args.length_unit)
    _report(args, targets, calib, arm, cams, topics)
    return 0


def _report(args, targets, calib, arm, cams, topics) -> None:
    if calib is not None:
        print(f"wrote {targets['camera_calibration.yaml']}: {'stereo' if calib.stereo else 'mono'}, "
              f"{calib.left.width}x{calib.left.height}{', rectified' if args.rectified else ''}, from "
              f"{' and '.join(map(str, topics))}", file=sys.stderr)
        stale = Path(args.out) / "handeye.yaml"
        if arm is None and stale.exists():
            print(f"graphtrack: note: {stale} was left as it was; one converted from a registration with the "
                  "cameras of before wants --dvrk-registration again", file=sys.stderr)
    if arm is not None:
        frame = "rectified left" if args.rectified or not cams else "left"
        print(f"wrote {targets['handeye.yaml']}: {arm} base in the {frame} camera's frame", file=sys.stderr)
        if not cams:
            print("graphtrack: note: without the cameras (--ros, --bag) the registration stays in the rectified "
                  "left camera's frame; for a recording of raw images give the left camera with --ros or --bag",
                  file=sys.stderr)


def add_parser(sub) -> None:
    p = sub.add_parser("calibration", formatter_class=HelpFormatter,
                       help="write camera_calibration.yaml and handeye.yaml from ROS and dVRK calibration files",
                       description=__doc__.split("\n\n", 1)[1])
    p.add_argument("--out", required=True, type=output_path, metavar="SEQ",
                   help="recording folder to write camera_calibration.yaml and handeye.yaml into")
    p.add_argument("--ros", nargs="+", action="extend", metavar="YAML", default=None,
                   help="ROS camera_info YAML: one (mono) or the left and the right camera's (stereo) (default: no camera_calibration.yaml)")
    p.add_argument("--bag", metavar="BAG", default=None,
                   help="read the cameras from this bag's camera_info messages instead (a ROS 1 .bag or a ROS 2 "
                        "bag folder) (default: not read)")
    p.add_argument("--camera-info-topic", nargs="+", action="extend", metavar="TOPIC", default=None,
                   help="--bag's left (and right) camera_info topic (default: the bag's only one, or the ones "
                        "with left and right in their names)")
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
