"""``graphtrack simulate OUT``: write a synthetic recording with exact ground truth."""
from __future__ import annotations

import re

from graphtrack.commands.common import HelpFormatter, mm_deg, output_path
from graphtrack.errors import InputError
from graphtrack.sim import simulate


def _size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m:
        raise InputError(f"--size must be HxW (e.g. 540x960), got {text!r}")
    return int(m.group(1)), int(m.group(2))


def add_parser(sub) -> None:
    p = sub.add_parser("simulate", help="write a synthetic dVRK recording with ground truth (truth.csv)",
                       formatter_class=HelpFormatter,
                       description="Render a synthetic dVRK PSM + Large Needle Driver recording in the "
                                   "sequence format, plus truth.csv (true E_t and tool tip).")
    p.add_argument("out", metavar="OUT", type=output_path, help="output folder")
    p.add_argument("--scene", default="structured", help="structured (white bench) or tissue")
    p.add_argument("--frames", type=int, default=300, help="number of frames (30 fps)")
    p.add_argument("--seed", type=int, default=0, help="random seed (same seed, same recording)")
    p.add_argument("--size", default="540x960", help="image size HxW")
    p.add_argument("--compressed", action="store_true", help="CompressedImage messages in the bag")
    p.add_argument("--image-format", choices=("png", "jpeg"), default="png",
                   help="image files of the folder form and compressed bag images (jpeg: quality 95)")
    p.add_argument("--form", default="bag", help="bag (ROS 1 bag) or folder (frames/ + joints.csv)")
    p.add_argument("--randomize", action="store_true",
                   help="randomized, harder recording (look, occlusions, out-of-view, smoke, blur, lighting, "
                        "hand-eye error up to 10 mm / 5 deg; writes scenario.json; "
                        "docs/randomized-recordings.md): robustness benchmarks and detector training")
    p.add_argument("--stereo", action="store_true",
                   help="also render the right camera (5 mm baseline, 2 deg vergence): right images, "
                        "K2/D2/R/T, labels_right.csv; the left recording is unchanged")
    p.add_argument("--shaft-angle", type=float, default=None, metavar="DEG",
                   help="the direction the shaft enters the image from, deg counter-clockwise from the "
                        "image's right (0: from the right, 90: from the top, 180: from the left) (default: "
                        "drawn from the seed, 20-65 or 115-160)")
    p.add_argument("--handeye-error", metavar="MM,DEG", default=None,
                   help="the size of handeye.yaml's error, translation and rotation, its directions drawn "
                        "from the seed (default: drawn, 2-5 mm / 1-3 deg, with --randomize 0-10 mm / 0-5 deg)")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a recording in OUT that was not simulated (refused otherwise)")
    p.set_defaults(func=run)


def run(args) -> int:
    if args.compressed and args.form == "folder":
        raise InputError("--compressed makes the bag's images CompressedImage messages; the folder form has "
                         "no bag (--image-format jpeg compresses its files)")
    out = simulate(args.out, scene=args.scene, frames=args.frames, seed=args.seed, size=_size(args.size),
                   compressed=args.compressed, form=args.form, randomize=args.randomize,
                   progress=args.progress, stereo=args.stereo, image_format=args.image_format,
                   overwrite=args.overwrite, shaft_angle=args.shaft_angle,
                   handeye_error=mm_deg(args.handeye_error, "--handeye-error"))
    print(f"wrote {out}")
    return 0
