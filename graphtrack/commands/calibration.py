"""``graphtrack calibration --out SEQ --ros LEFT.yaml [RIGHT.yaml] --dvrk-registration PSMx.json``:
camera_calibration.yaml and handeye.yaml from the files the dVRK's calibration tools write.

--ros takes ROS camera_calibration's camera_info YAMLs (ost.yaml, or left.yaml and
right.yaml of a stereo calibration: the left camera's first), --bag the same from a
bag's camera_info messages, --opencv a calibrateCamera / stereoCalibrate result saved by
OpenCV's FileStorage; --dvrk-registration takes dvrk_camera_registration's
PSMx-registration-open-cv.json (the PSM base in the camera's frame). The registration
was measured through the rectified left image: with the cameras it is turned into the raw
left camera's frame by the left rectification (ROS's R, OpenCV's stereoRectify R1), or
kept in the rectified one with --rectified (a recording of the rectified image topics).
Lengths are read in --length-unit and --registration-unit (ROS and the dVRK: metres) and
written as the recording format wants them (mm). Nothing is written unless every file
passes the checks tracking makes when it reads them.
"""
from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

from graphtrack.commands.common import HelpFormatter, output_path
from graphtrack.errors import InputError, read_text
from graphtrack.geometry.camera import load_calibration, save_calibration
from graphtrack.io import calibration_import as ci
from graphtrack.io import opencv_calibration as oc
from graphtrack.io.consistency import calibration_notes
from graphtrack.io.handeye import load_handeye, save_handeye
from graphtrack.io.topics import ARMS


def _targets(args) -> dict[str, Path]:
    out = Path(args.out)
    names = ((["camera_calibration.yaml"] if args.ros or args.bag or args.opencv else [])
             + (["handeye.yaml"] if args.dvrk_registration else []))
    if not names:
        raise InputError("nothing to write: give --ros, --bag or --opencv (camera_calibration.yaml) and/or "
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


#: loader errors about lengths, which a wrong unit option causes
_LENGTH_KEYS = ("'T'", "_tvec'")


def _write_all(files: dict[Path, tuple]) -> None:
    """For each path: (save, check, source, unit). Every file is saved beside its path and
    checked by the loader the tracker uses before any replaces its path: one the tracker
    would refuse raises its error (naming the path, the ``source`` it came from and, for a
    length, the ``unit`` option it was read with) and nothing is written (a folder made
    for them is removed again)."""
    staged = {p: p.with_name(p.name + ".partial") for p in files}
    made = [d for d in {p.parent for p in files} if not d.exists()]
    done = False
    try:
        for p, (save, check, source, unit) in files.items():
            try:
                p.parent.mkdir(parents=True, exist_ok=True)
                save(staged[p])
                check(staged[p])
            except OSError as e:
                raise InputError(f"{p}: cannot write ({e.strerror or e})") from None
            except InputError as e:   # what the writer or the tracker's reader refuses
                msg = str(e).replace(str(staged[p]), str(p))
                hint = f", its lengths read in {unit}" if any(k in msg for k in _LENGTH_KEYS) else ""
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


def _registration(args, R1):
    """(arm, camera-from-base) of --dvrk-registration, turned into the raw left camera's
    frame by R1 (None: kept in the rectified frame it was measured in)."""
    path = args.dvrk_registration
    read_text(path)   # a missing or unreadable file is said before the arm its name would give
    named = ci.arm_of(path)
    if args.arm and named and args.arm != named:
        raise InputError(f"{path}: the registration of {named}, but --arm {args.arm}")
    arm = args.arm or named
    if arm is None:
        raise InputError(f"{path}: its name does not start with PSM1, PSM2 or PSM3: name the arm with --arm")
    reg = ci.read_dvrk_registration(path, args.registration_unit)
    if "right" in reg.reference_frame.lower():
        print(f"graphtrack: warning: {path}: its reference-frame is {reg.reference_frame!r}: registered through "
              "the right camera? handeye.yaml is the left camera's", file=sys.stderr)
    return arm, (reg.transform if R1 is None else ci.handeye_to_raw(reg.transform, R1))


def _check_sources(args) -> None:
    given = [n for n, v in (("--ros", args.ros), ("--bag", args.bag), ("--opencv", args.opencv)) if v]
    if len(given) > 1:
        raise InputError(f"give the cameras once: {' and '.join(given)} both describe them")
    for name, value in (("--ros", args.ros), ("--camera-info-topic", args.camera_info_topic),
                        ("--opencv", args.opencv)):
        if value and len(value) > 2:
            raise InputError(f"{name} takes one or two, got {len(value)}")
    if args.camera_info_topic and not args.bag:
        raise InputError("--camera-info-topic names topics of --bag: give --bag")
    if args.rectified and not (args.ros or args.bag):
        raise InputError("--rectified describes the rectified cameras of --ros or --bag: give one")
    if (args.opencv_keys or args.image_size) and not args.opencv:
        raise InputError("--opencv-keys and --image-size describe --opencv's files: give --opencv")
    if args.registration_unit != "m" and not args.dvrk_registration:
        raise InputError("--registration-unit describes --dvrk-registration's file: give --dvrk-registration")


def _cameras(args):
    """(Calibration or None, R1 or None, sources): the cameras of --ros, --bag or --opencv
    and the left rectification a registration is turned by (None with --rectified or
    without cameras)."""
    if args.opencv:
        calib, R1 = oc.calibration_from_opencv(args.opencv, _keys(args.opencv_keys), _image_size(args.image_size),
                                               args.length_unit)
        return calib, R1, args.opencv
    cams, sources = (([ci.read_ros_camera(p) for p in args.ros], args.ros) if args.ros else
                     ci.read_bag_cameras(args.bag, args.camera_info_topic) if args.bag else ([], []))
    if not cams:
        return None, None, []
    calib = ci.calibration_from_ros(*cams, rectified=args.rectified, unit_m=args.length_unit or 1.0)
    return calib, (None if args.rectified else cams[0].R), sources


def _length_unit(text: str) -> float:
    """argparse type of --length-unit: m, mm, or a positive number of metres per unit."""
    if text in ci.UNITS_M:
        return ci.UNITS_M[text]
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 < value < 1e3:
        raise argparse.ArgumentTypeError(f"{text!r}: give m, mm, or metres per unit (e.g. 0.0025)")
    return value


def _unit_text(unit_m: float) -> str:
    return next((k for k, v in ci.UNITS_M.items() if v == unit_m), f"units of {unit_m:g} m")


def _keys(text: str | None) -> dict[str, str]:
    out = {}
    for item in filter(None, (text or "").split(",")):
        role, sep, name = item.partition("=")
        if not sep or not role.strip() or not name.strip():
            raise InputError(f"--opencv-keys: {item!r} is not ROLE=NAME (e.g. K1=M1,D1=D1)")
        out[role.strip()] = name.strip()
    return out


def _image_size(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    w, sep, h = text.lower().partition("x")
    if not (sep and w.isdigit() and h.isdigit() and int(w) > 0 and int(h) > 0):
        raise InputError(f"--image-size: {text!r} is not WIDTHxHEIGHT (e.g. 960x540)")
    return int(h), int(w)


def run(args) -> int:
    _check_sources(args)
    targets = _targets(args)
    calib, R1, sources = _cameras(args)
    arm, handeye = _registration(args, R1) if args.dvrk_registration else (None, None)
    files = {}
    if calib is not None:
        files[targets["camera_calibration.yaml"]] = (lambda p: save_calibration(p, calib), load_calibration,
                                                     " and ".join(map(str, sources)),
                                                     f"{_unit_text(args.length_unit or 1.0)}: see --length-unit")
    if handeye is not None:
        files[targets["handeye.yaml"]] = (lambda p: save_handeye(p, handeye, arm), lambda p: load_handeye(p, arm),
                                          args.dvrk_registration, f"{args.registration_unit}: see --registration-unit")
    _write_all(files)
    _report(args, targets, calib, arm, R1, sources)
    return 0


def _report(args, targets, calib, arm, R1, sources) -> None:
    if calib is not None:
        print(f"wrote {targets['camera_calibration.yaml']}: {'stereo' if calib.stereo else 'mono'}, "
              f"{calib.left.width}x{calib.left.height}{', rectified' if args.rectified else ''}, from "
              f"{' and '.join(map(str, sources))}", file=sys.stderr)
        for note in calibration_notes(calib, targets["camera_calibration.yaml"]):   # as track will warn
            print(f"graphtrack: warning: {note}", file=sys.stderr)
        stale = Path(args.out) / "handeye.yaml"
        if arm is None and stale.exists():
            print(f"graphtrack: note: {stale} was left as it was; one converted from a registration with the "
                  "cameras of before wants --dvrk-registration again", file=sys.stderr)
    if arm is not None:
        frame = "left" if R1 is not None else "rectified left"
        print(f"wrote {targets['handeye.yaml']}: {arm} base in the {frame} camera's frame", file=sys.stderr)
        if R1 is None and not args.rectified:
            print("graphtrack: note: without the cameras (--ros, --bag, --opencv) the registration stays in the "
                  "rectified left camera's frame: right for a recording of rectified images, off by the "
                  "rectification's rotation for raw ones", file=sys.stderr)


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
    p.add_argument("--opencv", nargs="+", action="extend", metavar="FILE", default=None,
                   help="or read them from OpenCV FileStorage files (calibrateCamera / stereoCalibrate results, "
                        "YAML, XML or JSON; names as OpenCV's samples write them, e.g. M1 D1 M2 D2 R T) "
                        "(default: not read)")
    p.add_argument("--opencv-keys", metavar="ROLE=NAME,...", default=None,
                   help="--opencv's names for the roles K1 D1 K2 D2 R T R1 (or a mono file's K D) where they "
                        "differ from the usual ones (default: found by name)")
    p.add_argument("--image-size", metavar="WxH", default=None,
                   help="the recorded images' size, for --opencv files that do not hold it (default: from the file)")
    p.add_argument("--rectified", action="store_true",
                   help="the recording holds the rectified images: describe the rectified cameras")
    p.add_argument("--dvrk-registration", metavar="JSON", default=None,
                   help="dvrk_camera_registration's PSMx-registration-open-cv.json (default: no handeye.yaml)")
    p.add_argument("--arm", choices=ARMS, default=None,
                   help="the arm of --dvrk-registration (default: from its file name)")
    p.add_argument("--length-unit", type=_length_unit, metavar="UNIT", default=None,
                   help="the unit of the cameras' stereo baseline: m, mm, or metres per unit (default: m, as ROS "
                        "writes it; an OpenCV stereo file, in the unit its square size was given in, needs it)")
    p.add_argument("--registration-unit", choices=tuple(ci.UNITS_M), default="m",
                   help="the unit of --dvrk-registration's translation (the dVRK's: m)")
    p.add_argument("--overwrite", action="store_true", help="replace existing files in --out")
    p.set_defaults(func=run)
