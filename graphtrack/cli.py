"""The ``graphtrack`` command line: one subcommand per module in graphtrack/commands.

Each command module defines ``add_parser(subparsers)`` (registering its
arguments and ``set_defaults(func=run)``) and ``run(args) -> int``. Bad input
(:class:`~graphtrack.errors.InputError`) is printed as one line and exits 2;
no traceback reaches the user for it. Before any numerical library loads, the
process's thread pools are set to ``--threads`` (default 1; :mod:`graphtrack.threads`).

Exit status: 0 success; 2 bad input, including a ``track``/``refine`` run that
tracked no frame (every frame skipped: the message gives the skip counts and
the first skipped frame; metrics.json is still written) and a full disk;
1 an internal error (a bug: one line asking for a report; set
``GRAPHTRACK_DEBUG=1`` for the traceback); 130 interrupted (Ctrl-C or SIGTERM).
"""
from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
from pathlib import Path

from graphtrack.commands.common import threads_from_args
from graphtrack.errors import InputError
from graphtrack.threads import DEFAULT_THREADS, limit_threads, set_thread_environment

#: Subcommands in the order ``--help`` lists them.
COMMANDS = ("demo", "simulate", "track", "refine", "detect", "compare", "robot", "calibration", "train")


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse's own usage errors: exit 2, one line
        self.print_usage(sys.stderr)
        self.exit(2, f"graphtrack: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="graphtrack",
                     description="Track dVRK surgical tools in endoscope video: estimate the lumped-error "
                                 "transform E (camera-from-base) from images and noisy joint readings.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"graphtrack.commands.{name}")
        except ModuleNotFoundError as e:
            if e.name == f"graphtrack.commands.{name}":
                continue  # command not built yet
            raise
        module.add_parser(sub)
    return parser



def _threads_in(argv: list[str]) -> int:
    """The --threads value in argv (default 1), read before numpy and torch load."""
    for i, a in enumerate(argv):
        v = a.split("=", 1)[1] if a.startswith("--threads=") else (
            argv[i + 1] if a == "--threads" and i + 1 < len(argv) else None)
        if v is not None:
            try:
                return max(1, int(v))
            except ValueError:
                return DEFAULT_THREADS  # argparse reports it
    return DEFAULT_THREADS


def _end_progress_bars() -> None:
    """Close any progress bar still open, so that a message starts on its own line."""
    from tqdm import tqdm

    for bar in list(getattr(tqdm, "_instances", ())):
        bar.close()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    set_thread_environment(_threads_in(argv))
    args = None
    previous = _stop_on_sigterm()
    try:
        parser = build_parser()   # imports the commands' libraries: Ctrl-C may come here too
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return 2
        if hasattr(args, "threads"):
            limit_threads(threads_from_args(args))
        return int(args.func(args) or 0)
    except InputError as e:
        _end_progress_bars()
        print(f"graphtrack: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        _end_progress_bars()
        out = getattr(args, "out", None)
        kept = f" (the files written so far in {out} are kept)" if out and Path(out).is_dir() else ""
        print(f"graphtrack: interrupted{kept}", file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001 - last resort: a bug, not bad input
        if os.environ.get("GRAPHTRACK_DEBUG"):
            raise
        _end_progress_bars()
        where = e.__traceback__
        while where is not None and where.tb_next is not None:
            where = where.tb_next
        at = f" at {Path(where.tb_frame.f_code.co_filename).name}:{where.tb_lineno}" if where else ""
        msg = (str(e).strip().splitlines() or [""])[0][:200]
        print(f"graphtrack: internal error: {type(e).__name__}{at}: {msg} (a bug: please report it with "
              "the command line; GRAPHTRACK_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _stop_on_sigterm():
    """SIGTERM (``kill``) stops a command as Ctrl-C does: the files written so far kept, a
    study's workers stopped. Returns the previous handler (None off the main thread)."""
    def stop(signum, frame):
        raise KeyboardInterrupt

    try:
        return signal.signal(signal.SIGTERM, stop)
    except ValueError:   # not the main thread
        return None


if __name__ == "__main__":
    sys.exit(main())
