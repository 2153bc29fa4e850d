"""``graphtrack train --out FILE``: train the learned detector's weights from simulated data.

One reproducible command: it simulates the training frames
(:func:`graphtrack.training.data.generate`: both scenes, domain
randomised, ground-truth shaft edges from truth), passes them through JPEG
(q 95) and trains the network (:mod:`graphtrack.training.fit`). The
shipped ``graphtrack/data/learned_detector.pt`` is

    graphtrack train --out graphtrack/data/learned_detector.pt --device cuda

i.e. the defaults: 2400 frames (100 recordings x 24; simulated in ~130 s on
one core), 60 epochs, batch 32, seed 0 (see docs/decisions/learned-detector.md
for the recipe of the current weights; ``--init`` fine-tunes existing weights). On an H100 the 60 epochs took 348 s
(the per-sample augmentation is Python-bound); on the CPU (``--device cpu``,
the same recipe and seed) expect roughly 0.15-0.3 s per frame and epoch on
one core, i.e. several hours for the full schedule.
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

from graphtrack.commands.common import HelpFormatter, add_threads_argument, output_path
from graphtrack.errors import InputError, check_seed


def add_parser(sub):
    p = sub.add_parser("train", help="train the learned detector on simulated frames",
                       formatter_class=HelpFormatter,
                       description="Simulate domain-randomised training frames (both scenes) and train the "
                                   "learned shaft-edge detector; writes a weights file for --detector learned.")
    p.add_argument("--out", required=True, type=output_path, metavar="FILE", help="weights file to write (.pt)")
    p.add_argument("--frames", type=int, default=2400, help="training frames to simulate")
    p.add_argument("--epochs", type=int, default=60, help="training epochs")
    p.add_argument("--seed", type=int, default=0, help="seed of the data and of the training")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu", help="training device")
    p.add_argument("--batch", type=int, default=32, help="batch size")
    p.add_argument("--lr", type=float, default=3e-3, help="peak learning rate (cosine decay to 1e-5)")
    p.add_argument("--init", metavar="WEIGHTS", help="fine-tune from this weights file (default: from scratch)")
    add_threads_argument(p)
    p.add_argument("--data", metavar="NPZ",
                   help="the simulated frames' .npz cache: written when missing, else reused as it is "
                        "(its frames, whatever --frames says) (default: none)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=run)


def command(args) -> str:
    """The ``graphtrack train`` command line that reproduces these weights (written into them)."""
    parts = [f"graphtrack train --out {args.out} --frames {args.frames} --epochs {args.epochs}",
             f"--seed {args.seed} --batch {args.batch} --lr {args.lr:g} --device {args.device}"]
    if args.init is not None:
        parts.append(f"--init {args.init}")
    if args.data is not None:
        parts.append(f"--data {args.data}")
    return " ".join(parts)


def _check_writable(path: Path, what: str) -> None:
    """InputError before any work when ``path`` cannot be written: a folder, a missing
    or read-only parent folder, a read-only file."""
    if path.is_dir():
        raise InputError(f"{path}: is a folder; {what} names a file")
    parent = path.parent
    if not parent.is_dir():
        raise InputError(f"{parent}: folder not found ({what})")
    if not os.access(parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise InputError(f"{path}: not writable ({what})")


def _check_arguments(args) -> None:
    if args.frames <= 0:
        raise InputError("--frames must be positive")
    if args.epochs < 1:
        raise InputError("--epochs must be at least 1 (0 would write untrained weights)")
    if args.batch <= 0:
        raise InputError("--batch must be positive")
    if not args.lr > 0:
        raise InputError("--lr must be positive")
    check_seed(args.seed)
    if args.init is not None and not Path(args.init).is_file():
        raise InputError(f"{args.init}: weights file not found")
    _check_writable(Path(args.out), "--out")
    if Path(args.out).suffix not in (".pt", ".pth"):
        raise InputError(f"--out {args.out}: name a .pt file (the weights are a torch state dict)")
    if args.data and not Path(args.data).is_file():
        _check_writable(Path(args.data), "--data")


def run(args) -> int:
    _check_arguments(args)
    # lazy: training loads torch (seconds), and the CLI imports every command module to build its parser
    import torch

    from graphtrack.training.data import generate, load_cache, save_cache
    from graphtrack.training.fit import jpeg_roundtrip, save, train

    if args.device == "cuda":
        if not torch.cuda.is_available():
            raise InputError("--device cuda: no CUDA device available")
    from graphtrack.detect.learned import load_weights
    for path, what in ((args.init, "--init"), (args.out if Path(args.out).exists() else None, "--out")):
        if path is not None:   # before the frames are simulated (minutes); --out: never a file of another kind
            try:
                load_weights(path)
            except InputError as e:
                raise InputError(f"{what} {e}" + ("; choose another --out" if what == "--out" else "")) from None
    out = Path(args.out)
    log = (lambda *a: None) if args.quiet else (lambda *a: print(*a, flush=True))
    t0 = time.perf_counter()
    cache = Path(args.data) if args.data else None
    if cache is not None and cache.is_file():
        images, segments = load_cache(cache)
        info = {"frames": len(images), "cached": str(cache)}
    else:
        images, segments, info = generate(args.frames, args.seed,
                                          progress=lambda k, n, s: log(f"simulated {k}/{n} frames ({s:.0f} s)"))
        if cache is not None:
            save_cache(cache, images, segments)
    images = jpeg_roundtrip(images)
    net, stats = train(images, segments, epochs=args.epochs, seed=args.seed, device=args.device,
                       batch=args.batch, lr=args.lr, log=log, init=args.init)
    meta = {"frames": int(len(images)), "seed": int(args.seed), **{k: v for k, v in stats.items()},
            "data": json.dumps(info), "total_seconds": round(time.perf_counter() - t0, 1),
            "command": command(args)}
    try:
        save(net, out, meta)
    except OSError as e:
        raise InputError(f"{out}: cannot write the weights ({e.strerror or e})") from None
    log(json.dumps({**meta, "data": info}))   # the weights keep meta flat (weights_only loading): data as text
    log(f"wrote {out}")
    return 0
