"""The study's report: table.md / table.csv / runtime.csv / results.csv and the
accumulated-error plots, read back from the cell folders of
:mod:`graphtrack.study.plan` (a cell is complete when it holds done.json).
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from graphtrack.errors import InputError
from graphtrack.eval.metrics import accumulated_error, tip_error_series
from graphtrack.io.labels import read_labels
from graphtrack.io.recording import same_recording
from graphtrack.io.trajectory import read_trajectory
from graphtrack.study.cells import CELL_OPTION_DEFAULTS, Cell


def is_done(cell: Cell) -> bool:
    """The cell holds a result made with its options from its recording as it is now
    (:func:`graphtrack.io.recording.fingerprint`; a done.json from before fingerprints is
    taken as it is)."""
    p = Path(cell.out) / "done.json"
    if not p.is_file():
        return False
    try:
        doc = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError):
        return False
    # a cell done before an option existed holds that option's default
    stored, wanted = ({**CELL_OPTION_DEFAULTS, **(o or {})} for o in (doc.get("options"), cell.options))
    if "recording" in doc and Path(cell.path).is_dir() and not same_recording(doc["recording"], cell.path):
        return False
    return stored == wanted and (Path(cell.out) / "metrics.json").is_file()


def recording_notes(cells: list[Cell]) -> list[str]:
    """The lines the cells' runs warned about their recordings (metrics.json's
    ``recording_warnings``), each once, in cell order: a study's cells run quietly; and
    one naming the recordings without labels.csv, whose accuracy entries are n/a."""
    lines: dict[str, None] = {}
    for cell in filter(is_done, cells):   # not a failed or out-of-date cell's
        try:
            doc = json.loads((Path(cell.out) / "metrics.json").read_text())
        except (OSError, json.JSONDecodeError):
            continue
        lines.update(dict.fromkeys(str(w) for w in doc.get("recording_warnings") or []))
    unlabelled = [rec for rec, path in dict.fromkeys((c.recording, c.path) for c in cells)
                  if not (Path(path) / "labels.csv").is_file()]
    if unlabelled:
        lines[f"no labels.csv in {', '.join(unlabelled)}: the tip error there is n/a and no accumulated-error "
              "plot is drawn; label the tool tip in some frames (docs/sequence-format.md, labels.csv) to "
              "compare accuracy"] = None
    return list(lines)


def cell_status(cell: Cell) -> dict:
    """{'state': 'done'|'error'|'missing', 'result': ..., 'error': ..., 'internal': a bug, not
    bad input} from the cell folder."""
    out = Path(cell.out)
    if is_done(cell):
        doc = json.loads((out / "done.json").read_text())
        return {"state": "done", "result": doc.get("result", {})}
    if (out / "error.json").is_file():
        try:
            doc = json.loads((out / "error.json").read_text())
        except (OSError, json.JSONDecodeError):
            doc = {}
        return {"state": "error", "error": doc.get("error", "failed"), "internal": bool(doc.get("internal"))}
    return {"state": "missing"}


def _fmt(x: float, nd: int = 2) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x:.{nd}f}"


#: results.csv columns that count frames: written as integers
COUNT_COLUMNS = ("frames_tracked", "frames_skipped")


def _count(x) -> str:
    return str(int(x)) if isinstance(x, (int, float)) and math.isfinite(x) else "n/a"


def _get(d: dict, *keys, default=float("nan")):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return default
        d = d[k]
    return d if d is not None else default


def _mean(values) -> float:
    """Mean of the finite values (NaN when none)."""
    v = [float(x) for x in values if x is not None and math.isfinite(float(x))]
    return sum(v) / len(v) if v else float("nan")


def _write_pair_table(path: Path, rows, recs, cells: dict, suffixes: tuple[str, str], digits: int) -> None:
    """A CSV with two columns per recording (``<rec><suffix>``) holding each cell's
    pair of numbers, or its state string (e.g. an error) and a blank."""
    with path.open("w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["observation", "estimator"] + [f"{r}{sfx}" for r in recs for sfx in suffixes])
        for row in rows:
            vals = []
            for r in recs:
                v = cells.get((row, r), "")
                vals += [v, ""] if isinstance(v, str) else [_fmt(v[0], digits), _fmt(v[1], digits)]
            w.writerow(list(row) + vals)


def _md_table(rows, recs, text) -> list[str]:
    """Markdown lines of a table: one line per (observation, estimator) row, one
    column per recording, ``text(row, recording)`` in each cell."""
    lines = ["| observation | estimator | " + " | ".join(recs) + " |", "|---|---|" + "---|" * len(recs)]
    return lines + [f"| {row[0]} | {row[1]} | " + " | ".join(text(row, r) for r in recs) + " |" for row in rows]


def write_tables(out: Path, cells: list[Cell], notes: list[str]) -> dict:
    """table.md, table.csv, runtime.csv, results.csv from the cell folders; returns the table data.

    A (row, recording) entry run with several seeds (the study's repeats)
    reports the mean over its runs of each run's figures; ``spread`` holds the
    per-seed means (min, max, count) of those entries. An entry with a failed
    run reads "error", one with a run not yet done "missing".
    """
    recs = list(dict.fromkeys(c.recording for c in cells))
    rows = list(dict.fromkeys(c.row for c in cells))
    status = [(c, cell_status(c)) for c in cells]
    groups: dict = {}
    for c, st in status:
        groups.setdefault((c.row, c.recording), []).append((c, st))
    errors, internal = [], 0
    acc, run, spread = {}, {}, {}
    for (row, rec), runs in groups.items():
        for c, st in runs:
            if st["state"] == "error":
                errors.append((rec, c.key, st["error"]))
                internal += st["internal"]
        states = {st["state"] for _, st in runs}
        if states != {"done"}:
            acc[row, rec] = run[row, rec] = "error" if "error" in states else "missing"
            continue
        res = [st["result"] for _, st in runs]
        means = [_get(r, "tip_error_percent_diagonal", "mean") for r in res]
        acc[row, rec] = (_mean(means), _mean([_get(r, "tip_error_percent_diagonal", "std") for r in res]))
        run[row, rec] = _runtime(res)
        if len(runs) > 1:
            spread[row, rec] = (min(means), max(means), len(runs))

    def acc_cell(v):
        return v if isinstance(v, str) else f"{_fmt(v[0])} ({_fmt(v[1])})"

    def run_cell_(v):
        return v if isinstance(v, str) else f"{_fmt(v[0], 1)} ({_fmt(v[1], 1)})"

    def seeds_cell(row, r):
        if (row, r) not in spread:
            return "1 seed"
        lo, hi, n = spread[row, r]
        return f"{_fmt(lo)} - {_fmt(hi)} ({n} seeds)"

    md = ["# Estimator comparison", "",
          "## Tool-tip error", "",
          "2-D tool-tip error against labels.csv in % of the image diagonal: mean (std).", ""]
    md += _md_table(rows, recs, lambda row, r: acc_cell(acc.get((row, r), "—")))
    if spread:
        md += ["", "Entries run with several seeds (a stochastic estimator or RANSAC lines) are the "
               "mean over the seeds; the per-seed means (% of the diagonal):", ""]
        md += _md_table([row for row in rows if any((row, r) in spread for r in recs)], recs, seeds_cell)
    md += ["", "## Runtime", "", "Milliseconds per frame, mean over the frames after the first (start-up and "
           "an offline finish not counted), and in brackets the frames per second it gives: 1000 / ms.", ""]
    md += _md_table(rows, recs, lambda row, r: run_cell_(run.get((row, r), "—")))
    plots = [f"accumulated_error_{r}.png" for r in recs if (out / f"accumulated_error_{r}.png").is_file()]
    if plots:
        md += ["", "## Accumulated error", ""] + [f"![{p}]({p})" for p in plots]
    if notes:
        md += ["", "## Notes", ""] + [f"- {n}" for n in notes]
    if errors:
        md += ["", "## Errors", ""] + [f"- {rec} / {key}: {msg}" for rec, key, msg in errors]
    (out / "table.md").write_text("\n".join(md) + "\n")

    _write_pair_table(out / "table.csv", rows, recs, acc, ("", "_std"), 4)
    _write_pair_table(out / "runtime.csv", rows, recs, run, ("_ms_mean", "_fps"), 3)
    _write_results(out / "results.csv", status)
    return {"recordings": recs, "rows": rows, "accuracy": acc, "runtime": run, "spread": spread,
            "errors": errors, "internal_errors": internal, "notes": notes}


def _write_results(path: Path, status: list) -> None:
    """results.csv: one row per run (cell, its state) with metrics.json's figures."""
    with path.open("w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        cols = ["tip_error_px.mean", "tip_error_px.median", "tip_error_px.p95",
                "tip_error_percent_diagonal.mean", "tip_error_percent_diagonal.std",
                "tip_error_percent_diagonal.median", "tip_error_percent_diagonal.p95",
                "tip_error_3d_mm.mean", "tip_error_3d_depth_mm.mean", "tip_error_3d_lateral_mm.mean",
                "translation_error_mm.mean", "rotation_error_deg.mean",
                "nees.mean", "runtime_ms.median", "fps", "fps_steady", "frames_tracked", "frames_skipped"]
        w.writerow(["recording", "observation", "estimator", "seed", "state"] + cols + ["error"])
        for c, st in status:
            r = st.get("result", {})
            w.writerow([c.recording, c.row[0], c.row[1], c.options.get("seed", ""), st["state"]]
                       + [_count(_get(r, k)) if k in COUNT_COLUMNS else _fmt(_get(r, *k.split(".")), 4)
                          for k in cols] + [st.get("error", "")])


def plot_accumulated(out: Path, cells: list[Cell]) -> list[Path]:
    """accumulated_error_<recording>.png: one curve per completed cell with labels (the
    study's own seed of a repeated one, as the title says; "(mono)" marks the mono cells
    of a study over both views)."""
    import matplotlib  # lazy: heavy, and only the plots need it (a study without plots never loads it)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    for rec in dict.fromkeys(c.recording for c in cells):
        mine = [c for c in cells if c.recording == rec and c.repeat == 0 and cell_status(c)["state"] == "done"]
        if not mine:
            continue
        lab_path = Path(mine[0].path) / "labels.csv"
        if not lab_path.is_file():
            continue
        labels = read_labels(lab_path)
        fig, ax = plt.subplots(figsize=(7, 4), dpi=110)
        drawn = 0
        colours, styles = _curve_styles(mine)
        for c in mine:
            res = cell_status(c)["result"]
            diag = res.get("image_diagonal_px")
            try:
                traj = read_trajectory(Path(c.out) / "trajectory.csv")
            except InputError:
                continue
            frames, errs = tip_error_series(traj, labels, diag)
            if len(frames) == 0:
                continue
            est = c.row[1]   # "(mono)" marked in a study over both views
            ax.plot(frames, accumulated_error(errs), label=est if c.observation is None else f"{est} / {c.observation}",
                    lw=1.4, color=colours[est], ls=styles[c.observation])
            drawn += 1
        ax.set_xlabel("frame")
        ax.set_ylabel("accumulated tip error (% of diagonal)")
        finals = [float(ln.get_ydata()[-1]) for ln in ax.get_lines() if math.isfinite(ln.get_ydata()[-1])]
        if finals and min(finals) > 0 and max(finals) / min(finals) > 5:   # kinematics would flatten the rest
            ax.set_yscale("log")
            ax.set_ylabel("accumulated tip error (% of diagonal, log scale)")
            plain = matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}")   # 0.2, not 2 x 10^-1
            ax.yaxis.set_minor_locator(matplotlib.ticker.LogLocator(subs=(2.0, 5.0)))
            ax.yaxis.set_major_formatter(plain)
            ax.yaxis.set_minor_formatter(plain)
        repeated = any(c.recording == rec and c.repeat > 0 for c in cells)   # table.csv: their seeds' mean
        ax.set_title(f"{rec}: running mean of the 2-D tool-tip error"
                     + (f"\n(repeated estimators: the run with seed {mine[0].options['seed']})" if repeated else ""),
                     fontsize=10)
        ax.grid(alpha=0.3)
        if drawn:
            ax.legend(fontsize=7, loc="best")
        fig.tight_layout()
        p = out / f"accumulated_error_{rec}.png"
        fig.savefig(p)
        plt.close(fig)
        written.append(p)
    return written


#: line styles told apart in a legend, one per observation model (six), solid without one
_STYLES = ("-", "--", ":", "-.", (0, (5, 1, 1, 1, 1, 1)), (0, (8, 2)))


def _curve_styles(cells: list[Cell]) -> tuple[dict, dict]:
    """(colour per estimator row label, line style per observation model) for one plot:
    every curve's pair differs (matplotlib's default cycle repeats its 10 colours)."""
    import matplotlib

    ests = list(dict.fromkeys(c.row[1] for c in cells))
    obs = list(dict.fromkeys(c.observation for c in cells))
    palette = matplotlib.colormaps["tab10" if len(ests) <= 10 else "tab20"]
    return ({e: palette(i % palette.N) for i, e in enumerate(ests)},
            {o: "-" if o is None else _STYLES[i % len(_STYLES)] for i, o in enumerate(obs)})


def _runtime(results: list[dict]) -> tuple[float, float]:
    """(ms, frames/s) of a cell's runs: the steady per-frame milliseconds (metrics.json
    ``frame_ms_mean``; ``runtime_ms.median`` for a run without it), averaged over the
    seeds, and 1000 / ms, so that the two numbers of a table entry always agree."""
    ms = _mean([r["frame_ms_mean"] if isinstance(r.get("frame_ms_mean"), (int, float))
                else _get(r, "runtime_ms", "median") for r in results])
    return ms, (1e3 / ms if ms and ms > 0 else float("nan"))


def format_table(data: dict) -> str:
    """The accuracy table as aligned plain text (for the terminal)."""
    recs = data["recordings"]
    head = ["observation", "estimator"] + recs
    lines = []
    for row in data["rows"]:
        vals = []
        for r in recs:
            v = data["accuracy"].get((row, r), "—")
            vals.append(v if isinstance(v, str) else f"{_fmt(v[0])} ({_fmt(v[1])})")
        lines.append(list(row) + vals)
    widths = [max(len(str(x)) for x in col) for col in zip(head, *lines)]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    return "\n".join([fmt.format(*head), fmt.format(*["-" * w for w in widths])]
                     + [fmt.format(*l) for l in lines])
