"""Running a study's cells (:mod:`graphtrack.study.plan`): one cell into its folder.

A cell is one ``graphtrack track`` run with the cell's options
(:meth:`Cell.track_options`). Its folder
gets ``done.json`` LAST (the mark of a complete cell) or ``error.json`` (a
failed cell: reported, retried next time; the study goes on). Executors: local
processes (:func:`run_local`, ``workers``) or Ray tasks (:func:`run_ray`),
whose workers may not share the study folder's file system, so they return
the files and the driver writes them (:func:`run_cell_portable`).
"""
from __future__ import annotations

import json
import logging
import multiprocessing as mp
import os
import re
import socket
import shutil
import sys
import tempfile
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict
from pathlib import Path

import numpy as np
from tqdm import tqdm

from graphtrack.errors import InputError
from graphtrack.io.recording import fingerprint
from graphtrack.study.cells import Cell
from graphtrack.threads import THREAD_ENV, limit_threads
from graphtrack.track import track


def _track_into(cell: Cell, out: Path) -> dict:
    limit_threads(1)  # parallelism is across cells: one thread per worker
    # a cell that tracked nothing fails (InputError), as `track` would; a retried cell's
    # folder holds its failed attempt's files
    return track(cell.path, out, cell.track_options(), video=cell.video, progress=False,
                 max_frames=cell.options["max_frames"], quiet=True, topics=cell.topics(), overwrite=True)


def _json_safe(x):
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    return x


def _finish(cell: Cell, result: dict, seconds: float) -> dict:
    out = Path(cell.out)
    (out / "error.json").unlink(missing_ok=True)
    doc = {"cell": asdict(cell), "options": cell.options, "seconds": seconds, "result": _json_safe(result),
           "recording": fingerprint(cell.path)}
    tmp = out / "done.json.tmp"
    tmp.write_text(json.dumps(doc, indent=2))
    os.replace(tmp, out / "done.json")  # last: marks the cell complete
    return {"key": cell.key, "recording": cell.recording, "ok": True, "seconds": seconds}


def _error(e: BaseException) -> dict:
    """error.json's content for a cell that raised ``e``: ``internal`` unless it is bad input."""
    internal = not isinstance(e, InputError)
    return {"error": f"{type(e).__name__}: {e}" if internal else str(e), "internal": internal,
            "traceback": traceback.format_exc()}


def _fail(cell: Cell, err: dict) -> dict:
    out = Path(cell.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / "error.json").write_text(json.dumps(err, indent=2))
    except OSError:
        pass
    return {"key": cell.key, "recording": cell.recording, "ok": False, "error": err["error"]}


def run_cell(cell: Cell) -> dict:
    """Run one cell into its folder (local processes). Never raises for a cell's own failure."""
    out = Path(cell.out)
    (out / "done.json").unlink(missing_ok=True)
    t = time.perf_counter()
    try:
        result = _track_into(cell, out)
    except Exception as e:  # noqa: BLE001 - a failing cell is reported, the study goes on
        return _fail(cell, _error(e))
    return _finish(cell, result, time.perf_counter() - t)


def run_cell_portable(cell: Cell) -> tuple[dict, dict[str, bytes] | None, dict | None]:
    """Run one cell in a scratch folder and return (result, {file: bytes}, error.json's content).

    For Ray workers that may not share the study folder's file system: the
    driver writes the files into the cell folder (the recording must still be
    readable at ``cell.path`` on the worker).
    """
    tmp = Path(tempfile.mkdtemp(prefix="graphtrack-cell-"))
    t = time.perf_counter()
    try:
        result = _track_into(cell, tmp)
        files = {p.name: p.read_bytes() for p in tmp.iterdir() if p.is_file()}
        result["_seconds"] = time.perf_counter() - t
        return _json_safe(result), files, None
    except Exception as e:  # noqa: BLE001
        return {}, None, _error(e)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _store_portable(cell: Cell, answer) -> dict:
    result, files, err = answer
    if err is not None:
        return _fail(cell, err)
    out = Path(cell.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, data in files.items():
        (out / name).write_bytes(data)
    return _finish(cell, result, float(result.pop("_seconds", float("nan"))))


# -- executors ---------------------------------------------------------------------------
def _bar(total: int, quiet: bool):
    return tqdm(total=total, desc="study", unit="cell", file=sys.stderr, disable=quiet)


def run_local(cells: list[Cell], workers: int = 1, quiet: bool = False) -> list[dict]:
    answers = []
    with _bar(len(cells), quiet) as bar:
        if workers <= 1 or len(cells) <= 1:
            for c in cells:
                bar.set_postfix_str(f"{c.recording}/{c.key}")
                answers.append(run_cell(c))
                bar.update(1)
            return answers
        ex = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"), initializer=_worker_init)
        try:
            futures = {ex.submit(run_cell, c): c for c in cells}
            for fut in as_completed(futures):
                c = futures[fut]
                try:
                    answers.append(fut.result())
                except Exception as e:  # noqa: BLE001 - e.g. a worker killed by the OS
                    answers.append(_fail(c, _error(e)))
                bar.update(1)
        except BaseException:   # Ctrl-C or SIGTERM: no queued cell starts, the running ones stop
            for proc in list((getattr(ex, "_processes", None) or {}).values()):
                proc.terminate()
            ex.shutdown(wait=False, cancel_futures=True)
            raise
        ex.shutdown()
    return answers


def _worker_init() -> None:
    """A study worker ignores Ctrl-C, which the terminal sends to the whole process group:
    the parent stops the study (a worker interrupted mid-import marked its cells failed).
    On Linux it also ends with its parent (PR_SET_PDEATHSIG) instead of living on, orphaned,
    when the parent is killed."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(signal.SIGTERM))   # 1: PR_SET_PDEATHSIG
    except (OSError, AttributeError):   # not Linux
        pass


RAY_CONNECT_TIMEOUT_S = 10.0  #: a cluster address that does not answer within this is refused


def check_ray_address(address: str) -> None:
    """InputError unless ``address`` is 'local', 'auto' or a cluster address (``host:port``
    or ``ray://host:port``) that accepts a TCP connection within RAY_CONNECT_TIMEOUT_S: Ray
    itself retries an unreachable address for many minutes. Needs no Ray installed."""
    if address in ("local", "auto"):
        return
    m = re.fullmatch(r"(?:\w+://)?\[?([^\]\s]+?)\]?:(\d+)/?", address)
    if not m:
        raise InputError(f"--ray {address}: expected 'local', 'auto' or a cluster address HOST:PORT "
                         "(or ray://HOST:PORT)")
    try:
        socket.create_connection((m.group(1), int(m.group(2))), timeout=RAY_CONNECT_TIMEOUT_S).close()
    except (OSError, ValueError) as e:
        raise InputError(f"--ray {address}: no Ray cluster answers there "
                         f"({getattr(e, 'strerror', None) or e})") from None


def run_ray(cells: list[Cell], address: str, workers: int | None = None, quiet: bool = False) -> list[dict]:
    """Run the cells as Ray tasks. address: 'local' (start a local instance),
    'auto' (the running cluster) or a cluster address (ray://host:10001, host:6379),
    already checked by the caller (:func:`check_ray_address`, as ``run_study`` does)."""
    try:
        import ray  # optional and heavy: only a study run on Ray imports it
    except ImportError:
        raise InputError("--ray needs Ray: pip install 'graphtrack[ray]'") from None
    started = False
    if not ray.is_initialized():
        kw = {"ignore_reinit_error": True, "include_dashboard": False, "log_to_driver": False}
        if quiet:   # --quiet: not Ray's own start-up lines either (its warnings, "Started a local Ray instance")
            kw["logging_level"] = logging.ERROR
        try:
            if address == "local":
                # workers find graphtrack where this process found it (also when not installed)
                pkg_root = str(Path(__file__).resolve().parents[2])
                kw["runtime_env"] = {"env_vars": {"PYTHONPATH": os.pathsep.join(
                    [pkg_root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]),
                    **{v: "1" for v in THREAD_ENV}}}
                ray.init(num_cpus=workers or None, **kw)
            else:
                ray.init(address=address, **kw)
        except Exception as e:  # noqa: BLE001 - connection errors of many kinds
            raise InputError(f"--ray {address}: cannot connect to Ray ({type(e).__name__}: {e})") from None
        started = True
    remote = ray.remote(num_cpus=1, max_retries=1)(run_cell_portable)
    answers = []
    try:
        pending = {remote.remote(c): c for c in cells}
        with _bar(len(cells), quiet) as bar:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    c = pending.pop(ref)
                    try:
                        answers.append(_store_portable(c, ray.get(ref)))
                    except Exception as e:  # noqa: BLE001 - worker crash, lost node
                        answers.append(_fail(c, _error(e)))
                    bar.update(1)
    finally:
        if started:
            ray.shutdown()
    return answers
