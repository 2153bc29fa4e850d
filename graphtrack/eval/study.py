"""Estimator comparison studies: every (recording, estimator, observation model) cell.

A study folder DIR holds:

- ``study.json``: the options every cell was run with (refusing to mix: a
  second run with other options raises InputError) and the last request;
- ``runs/<recording>/<estimator>-<observation>/``: one ``graphtrack track``
  output per cell (trajectory.csv, trajectory.tum, metrics.json, ...) and
  ``done.json``, written LAST: a cell with done.json is complete and is not
  recomputed, so an interrupted study continues where it stopped. A cell that
  failed holds ``error.json`` instead (and is retried next time). The
  kinematics baseline ignores the observation model: one cell
  ``runs/<recording>/kinematics/`` per recording;
- ``table.md`` / ``table.csv``: the method's Table I (rows: observation model x
  estimator, columns: recordings, cells: mean (std) 2-D tip error in % of the
  image diagonal), the runtime table (median ms/frame, fps; also
  ``runtime.csv``), every cell's numbers in ``results.csv``, and the errors;
- ``accumulated_error_<recording>.png``: the running mean of the 2-D tip error
  over frames, one curve per cell (the method's Fig. 4).

Repeats (``repeats`` N > 1): a cell whose result depends on the seed (a
stochastic estimator, i.e. the particle filter's resampling, or an observation
model that fits RANSAC lines) is run with seeds seed, seed+1, ..., seed+N-1
(the first in ``<estimator>-<observation>/``, the others in
``<estimator>-<observation>.seed<S>/``) and the tables report the mean over
the N runs, with their spread; results.csv keeps every run. One seed of a
particle filter is one draw: on the benchmark's structured recording, four
filter seeds of line-intensities-polar gave 4.5, 5.9, 9.5 and 6.8 px.

Cells run in local processes (``workers``) or as Ray tasks (``ray_address``).
"""
from __future__ import annotations

import argparse
import importlib
import json
import os
import shutil
import sys
import tempfile
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from graphtrack.errors import InputError
# the report is read back from the cell folders; format_table / cell_status are re-exported
from graphtrack.eval.study_report import cell_status, format_table, is_done, plot_accumulated, write_tables  # noqa: F401

STUDY_VERSION = 1
#: Options that change a cell's result: a study folder holds one value of each.
CELL_OPTIONS = ("detector", "weights", "max_frames", "particles", "lag", "smoother", "seed",
                "alpha", "beta", "markers")


@dataclass
class StudyOptions:
    estimators: list[str] = field(default_factory=lambda: ["kinematics", "pf", "smoother", "batch"])
    observations: list[str] = field(default_factory=lambda: ["line-intensities"])
    detector: str = "learned"
    weights: str | None = None
    max_frames: int | None = None
    particles: int = 1000
    lag: float = 1.0
    smoother: str = "isam2"
    seed: int = 0
    alpha: float = 10.0
    beta: float = 0.9
    markers: bool = True
    repeats: int = 1        #: runs (seeds seed .. seed+repeats-1) of each seed-dependent cell

    def cell_options(self) -> dict:
        return {k: getattr(self, k) for k in CELL_OPTIONS}


@dataclass
class Cell:
    recording: str          # display name (folder name under runs/)
    path: str               # the recording's path
    estimator: str
    observation: str | None  # None for kinematics
    out: str                # the cell's output folder
    options: dict           # StudyOptions.cell_options()
    video: bool = False     # also write overlay.mp4
    repeat: int = 0         # 0: the study's seed; r: a repeat with seed + r (its options' seed)

    @property
    def key(self) -> str:
        k = self.estimator if self.observation is None else f"{self.estimator}-{self.observation}"
        return k if self.repeat == 0 else f"{k}.seed{self.options['seed']}"

    @property
    def row(self) -> tuple[str, str]:
        return ("—" if self.observation is None else self.observation, self.estimator)


# -- which combinations exist -----------------------------------------------------------
def supported_observations(estimator: str) -> tuple[str, ...] | None:
    """Observation models ``estimator`` accepts (None: all of them).

    Read from the estimator class's ``observation_models`` (or
    ``supported_observations``) attribute, without building it.
    """
    from graphtrack.estimate import ESTIMATORS

    module, cls = ESTIMATORS[estimator]
    try:
        klass = getattr(importlib.import_module(module), cls)
    except (ImportError, AttributeError):
        return None
    for attr in ("observation_models", "supported_observations", "OBSERVATION_MODELS"):
        v = getattr(klass, attr, None)
        if v is not None and not callable(v):
            return tuple(v)
    return None


def seed_dependent(estimator: str, observation: str | None) -> bool:
    """Whether a cell's result depends on the seed: a ``stochastic`` estimator
    class (the particle filter) or an observation model that draws RANSAC samples."""
    from graphtrack.detect.observe import SEEDED_MODELS
    from graphtrack.estimate import ESTIMATORS

    if estimator == "kinematics":
        return False
    module, cls = ESTIMATORS[estimator]
    try:
        stochastic = bool(getattr(getattr(importlib.import_module(module), cls), "stochastic", False))
    except (ImportError, AttributeError):
        stochastic = False
    return stochastic or observation in SEEDED_MODELS


def recording_names(paths: list[str]) -> list[str]:
    """Unique, readable names for the recordings (folder names, numbered on clashes)."""
    names, seen = [], {}
    for p in paths:
        base = Path(p).resolve()
        name = base.name if base.is_dir() else base.stem
        name = "".join(c if c.isalnum() or c in "-_." else "_" for c in name) or "recording"
        if name in seen:
            seen[name] += 1
            name = f"{name}_{seen[name]}"
        else:
            seen[name] = 1
        names.append(name)
    return names


def plan(paths: list[str], options: StudyOptions, out: Path,
         names: list[str] | None = None) -> tuple[list[Cell], list[str]]:
    """The cells to run, in table order, and notes about skipped combinations.

    names: the recordings' names in the tables and under runs/ (default: folder names).
    """
    cells, notes = [], []
    opts = options.cell_options()
    names = list(names) if names is not None else recording_names(paths)
    for est in options.estimators:
        if est == "kinematics":
            continue
        sup = supported_observations(est)
        if sup is not None:
            bad = [o for o in options.observations if o not in sup]
            if bad:
                notes.append(f"{est} does not support {', '.join(bad)}: skipped")
    for name, path in zip(names, paths):
        root = out / "runs" / name
        if "kinematics" in options.estimators:
            cells.append(Cell(name, str(Path(path).resolve()), "kinematics", None,
                              str(root / "kinematics"), opts))
        for obs in options.observations:
            for est in options.estimators:
                if est == "kinematics":
                    continue
                sup = supported_observations(est)
                if sup is not None and obs not in sup:
                    continue
                n = options.repeats if seed_dependent(est, obs) else 1
                for r in range(n):
                    o = opts if r == 0 else dict(opts, seed=opts["seed"] + r)
                    folder = f"{est}-{obs}" if r == 0 else f"{est}-{obs}.seed{o['seed']}"
                    cells.append(Cell(name, str(Path(path).resolve()), est, obs, str(root / folder), o,
                                      repeat=r))
    return cells, notes


# -- study.json: one set of options per folder ------------------------------------------
def check_study_folder(out: Path, options: StudyOptions, cells: list[Cell]) -> None:
    """Create or check DIR/study.json; refuse a folder made with other options."""
    doc_path = out / "study.json"
    recordings = {c.recording: c.path for c in cells}
    if doc_path.is_file():
        try:
            old = json.loads(doc_path.read_text())
        except (OSError, json.JSONDecodeError):
            raise InputError(f"{doc_path}: unreadable study.json; use another --out or remove it") from None
        old_opts = old.get("options", {})
        diff = [k for k in CELL_OPTIONS if old_opts.get(k) != options.cell_options()[k]]
        if diff:
            what = ", ".join(f"{k}: {old_opts.get(k)!r} there, {options.cell_options()[k]!r} now"
                             for k in diff)
            raise InputError(f"{out}: holds a study made with other options ({what}); "
                             f"use another --out, or the same options to continue it")
        old_recs = old.get("recordings", {})
        clash = [n for n, p in recordings.items() if n in old_recs and old_recs[n] != p]
        if clash:
            raise InputError(f"{out}: recording name {clash[0]!r} there is {old_recs[clash[0]]}, "
                             f"not {recordings[clash[0]]}; use another --out")
        recordings = {**old_recs, **recordings}
    try:
        out.mkdir(parents=True, exist_ok=True)
        doc = {"version": STUDY_VERSION, "options": options.cell_options(),
               "estimators": options.estimators, "observations": options.observations,
               "repeats": options.repeats, "recordings": recordings}
        tmp = doc_path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(doc, indent=2))
        os.replace(tmp, doc_path)
    except OSError as e:
        raise InputError(f"{out}: cannot write the study folder ({e.strerror})") from None


# -- running one cell -----------------------------------------------------------------
def track_options(cell: Cell):
    """The TrackOptions of a cell, exactly as ``graphtrack track`` would build them."""
    from graphtrack.commands.track import options_from_args

    o = cell.options
    args = argparse.Namespace(estimator=cell.estimator, observation=cell.observation or "line-intensities",
                              detector=o["detector"], weights=o["weights"], no_markers=not o["markers"],
                              particles=o["particles"], lag=o["lag"], smoother=o["smoother"], seed=o["seed"],
                              alpha=o["alpha"], beta=o["beta"])
    return options_from_args(args)


def _track_into(cell: Cell, out: Path) -> dict:
    from graphtrack.track import track

    return track(cell.path, out, track_options(cell), video=cell.video, progress=False,
                 max_frames=cell.options["max_frames"], quiet=True)


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
    doc = {"cell": asdict(cell), "options": cell.options, "seconds": seconds, "result": _json_safe(result)}
    tmp = out / "done.json.tmp"
    tmp.write_text(json.dumps(doc, indent=2))
    os.replace(tmp, out / "done.json")  # last: marks the cell complete
    return {"key": cell.key, "recording": cell.recording, "ok": True, "seconds": seconds}


def _fail(cell: Cell, e: BaseException) -> dict:
    msg = f"{type(e).__name__}: {e}" if not isinstance(e, InputError) else str(e)
    out = Path(cell.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / "error.json").write_text(json.dumps({"error": msg, "traceback": traceback.format_exc()},
                                                   indent=2))
    except OSError:
        pass
    return {"key": cell.key, "recording": cell.recording, "ok": False, "error": msg}


def run_cell(cell: Cell) -> dict:
    """Run one cell into its folder (local processes). Never raises for a cell's own failure."""
    out = Path(cell.out)
    (out / "done.json").unlink(missing_ok=True)
    t = time.perf_counter()
    try:
        result = _track_into(cell, out)
    except Exception as e:  # noqa: BLE001 - a failing cell is reported, the study goes on
        return _fail(cell, e)
    return _finish(cell, result, time.perf_counter() - t)


def run_cell_portable(cell: Cell) -> tuple[dict, dict[str, bytes] | None, str | None]:
    """Run one cell in a scratch folder and return (result, {file: bytes}, error).

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
        msg = f"{type(e).__name__}: {e}" if not isinstance(e, InputError) else str(e)
        return {}, None, msg + "\n" + traceback.format_exc()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _store_portable(cell: Cell, answer) -> dict:
    result, files, err = answer
    out = Path(cell.out)
    out.mkdir(parents=True, exist_ok=True)
    if err is not None:
        msg, _, tb = err.partition("\n")
        (out / "error.json").write_text(json.dumps({"error": msg, "traceback": tb}, indent=2))
        return {"key": cell.key, "recording": cell.recording, "ok": False, "error": msg}
    for name, data in files.items():
        (out / name).write_bytes(data)
    return _finish(cell, result, float(result.pop("_seconds", float("nan"))))


# -- executors ---------------------------------------------------------------------------
def _bar(total: int, quiet: bool):
    from tqdm import tqdm

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
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as ex:
            futures = {ex.submit(run_cell, c): c for c in cells}
            for fut in as_completed(futures):
                c = futures[fut]
                try:
                    answers.append(fut.result())
                except Exception as e:  # noqa: BLE001 - e.g. a worker killed by the OS
                    answers.append(_fail(c, e))
                bar.update(1)
    return answers


def run_ray(cells: list[Cell], address: str, workers: int | None = None, quiet: bool = False) -> list[dict]:
    """Run the cells as Ray tasks. address: 'local' (start a local instance),
    'auto' (the running cluster) or a cluster address (ray://host:10001, host:6379)."""
    try:
        import ray
    except ImportError:
        raise InputError("--ray needs Ray: pip install 'graphtrack[ray]'") from None
    started = False
    if not ray.is_initialized():
        kw = {"ignore_reinit_error": True, "include_dashboard": False, "log_to_driver": False}
        try:
            if address == "local":
                # workers find graphtrack where this process found it (also when not installed)
                pkg_root = str(Path(__file__).resolve().parents[2])
                kw["runtime_env"] = {"env_vars": {"PYTHONPATH": os.pathsep.join(
                    [pkg_root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])}}
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
                        answers.append(_fail(c, e))
                    bar.update(1)
    finally:
        if started:
            ray.shutdown()
    return answers


# -- the whole study ----------------------------------------------------------------------
def run_study(paths: list[str], out: str | Path, options: StudyOptions, workers: int = 1,
              ray_address: str | None = None, quiet: bool = False, video=None,
              names: list[str] | None = None) -> dict:
    """Run (or continue) a study; write the tables and plots; return the table data
    plus ``ran`` (cells computed now), ``reused`` (cells already done) and ``cells``.

    video: optional predicate Cell -> bool selecting cells that also write
    overlay.mp4 (a done cell without its video is recomputed).
    """
    out = Path(out)
    if not paths:
        raise InputError("no recordings given")
    for p in paths:
        if not Path(p).exists():
            raise InputError(f"{p}: recording not found")
    if workers < 1:
        raise InputError("--workers must be at least 1")
    if options.repeats < 1:
        raise InputError("--repeats must be at least 1")
    cells, notes = plan([str(p) for p in paths], options, out, names)
    if not cells:
        raise InputError("no estimator/observation combination to run")
    check_study_folder(out, options, cells)
    if video is not None:
        for c in cells:
            c.video = bool(video(c))
    todo = [c for c in cells if not is_done(c) or (c.video and not (Path(c.out) / "overlay.mp4").is_file())]
    if ray_address:
        run_ray(todo, ray_address, workers if workers > 1 else None, quiet) if todo else []
    else:
        run_local(todo, workers, quiet)
    plot_accumulated(out, cells)
    data = write_tables(out, cells, notes)
    data["ran"] = len(todo)
    data["reused"] = len(cells) - len(todo)
    data["cells"] = cells
    return data
