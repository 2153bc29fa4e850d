"""``graphtrack robot ARM.json TOOL.json --out robot.json``: robot.json from the dVRK's own files.

The dVRK describes a PSM in two configuration files: the arm (joints 1-3, e.g.
``psm.json``) and the tool (joints 4-6 and the jaw, e.g.
``LARGE_NEEDLE_DRIVER_400006.json``). They hold the kinematics but nothing the
camera sees, so the visual features (shaft cylinder, painted markers, tool
tip, skeleton) come from ``--features-from`` (a robot.json) or, by default,
graphtrack's Large Needle Driver model. The result is checked by loading it
back.
"""
from __future__ import annotations

import sys
from pathlib import Path

from graphtrack.commands.common import HelpFormatter, output_path
from graphtrack.errors import InputError
from graphtrack.robot.description import (load_dvrk_config, load_robot_json, parse_robot,
                                          save_robot_json)
from graphtrack.robot.psm import psm_large_needle_driver


def run(args) -> int:
    out = Path(args.out)
    if out.exists() and not args.overwrite:
        raise InputError(f"{out}: already exists (pass --overwrite to replace it)")
    if args.features_from:
        features, source = load_robot_json(args.features_from), args.features_from
    else:
        features, source = psm_large_needle_driver(), "graphtrack's Large Needle Driver model"
    robot = load_dvrk_config(args.arm_config, args.tool_config, features_from=features)
    # checked before anything is written: an error names the inputs, not the file not yet written
    try:
        parse_robot(robot.to_json(), Path(f"{args.arm_config} + {args.tool_config} with the features of {source}"))
    except InputError as e:
        hint = "" if robot.has_gripper else (f" ({args.tool_config} has no 'jaw' section, so the chain has no "
                                             "jaw links: if the tool has jaws (a needle driver, forceps), add "
                                             "\"jaw\": {} to the tool file, as an older dVRK file may leave them "
                                             "out; if it has none, give --features-from a robot.json of a tool "
                                             "without a jaw)")
        raise InputError(f"{e}{hint}") from None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        save_robot_json(out, robot)
    except OSError as e:
        raise InputError(f"{out}: cannot write ({e.strerror or e})") from None
    load_robot_json(out)
    print(f"wrote {out}: {robot.n_dh} DH joints{' + jaw' if robot.has_gripper else ''} from "
          f"{args.arm_config} and {args.tool_config}; visual features from {source}", file=sys.stderr)
    if not args.features_from:
        print("graphtrack: note: check shaft_features, point_features and tool_tip against your tool "
              "(docs/sequence-format.md, robot.json)", file=sys.stderr)
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("robot", help="write robot.json from the dVRK's arm and tool configuration files",
                       formatter_class=HelpFormatter,
                       description=__doc__.split("\n\n", 1)[1].replace("``", ""))
    p.add_argument("arm_config", metavar="ARM.json", help="dVRK arm file (joints 1-3), e.g. psm.json")
    p.add_argument("tool_config", metavar="TOOL.json",
                   help="dVRK tool file (joints 4-6, jaw), e.g. LARGE_NEEDLE_DRIVER_400006.json")
    p.add_argument("--out", required=True, type=output_path, metavar="FILE", help="robot.json to write")
    p.add_argument("--features-from", metavar="ROBOT.json", default=None,
                   help="take the visual features from this robot.json (default: graphtrack's Large Needle Driver model)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.set_defaults(func=run)
