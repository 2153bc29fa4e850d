"""Run every benchmark on ONE core and rewrite benchmarks/RESULTS.md.

    python benchmarks/run_all.py            # all of them (tens of minutes)
    python benchmarks/run_all.py sim pf     # a subset; other sections keep their last figures

Each ``benchmarks/bench_<name>.py`` exposes ``run(results: dict)`` filling
``results[<name>]`` with figures. This runner pins the process to one CPU core
(and one thread for numpy/OpenCV/torch), keeps the figures of every section in
``benchmarks/results.json`` and renders RESULTS.md: the machine, each target
next to its measured value, then every section's figures and tables. Each section
keeps the machine and date it was measured on: when a subset is re-run on another
machine, RESULTS.md names each section's and each target's machine, since timings
from two machines do not compare.
Timings are medians over repeated runs after warm-up (see each benchmark).
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import datetime  # noqa: E402
import importlib  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

HERE = Path(__file__).resolve().parent
SECTIONS = ("sim", "detect", "pf", "smoother", "track", "accuracy", "robustness", "stereo", "stereo_speed",
            "orientation")
RENDERED = SECTIONS + ("scaling",)

#: (section, key, what, target, ">=" | "<=", unit). Keys missing from the results show as "not measured".
TARGETS = [
    ("sim", "structured_fps", "simulator, 540x960 structured, render + write", 10, ">=", "frames/s"),
    ("sim", "tissue_fps", "simulator, 540x960 tissue, render + write", 10, ">=", "frames/s"),
    ("detect", "learned.structured.free.ms", "learned detector at 540x960 incl. segment extraction, structured",
     30, ">=fps", "frames/s"),
    ("detect", "learned.tissue.free.ms", "learned detector at 540x960 incl. segment extraction, tissue",
     30, ">=fps", "frames/s"),
    ("pf", "step_ms_1000", "PF predict+update, 1000 particles, ~500 px, 4 markers, shaft end", 3, "<=", "ms"),
    ("smoother", "online_lag1.0_median_ms", "smoother online update (median), 1 s lag, ~500 px + markers",
     3, "<=", "ms"),
    ("smoother", "batch_s", "batch refinement of 1800 frames", 20, "<=", "s"),
    ("smoother", "nees_mc_mean", "smoother mean NEES, 200 independent synthetic runs (6 DOF)",
     (5.53, 6.49), "in", ""),
    ("track", "fps_540_canny_smoother", "track 540x960, canny + smoother", 60, ">=", "frames/s"),
    ("track", "fps_540_learned_smoother", "track 540x960, learned + smoother", 30, ">=", "frames/s"),
    ("track", "fps_540_learned_smoother_busy_threads1",
     "track 540x960, learned + smoother, a busy core beside it (own process, --threads 1)", 30, ">=", "frames/s"),
    ("track", "fps_1080_canny_smoother", "track 1080x1920, canny + smoother", 30, ">=", "frames/s"),
    ("track", "fps_1080_canny_pf", "track 1080x1920, canny + particle filter (1000)", 30, ">=", "frames/s"),
    ("robustness", "converged15_pf", "PF converges within 15 frames (randomized, held out)", 0.95, ">=", ""),
    ("robustness", "converged15_smoother", "smoother converges within 15 frames (randomized, held out)", 0.95,
     ">=", ""),
    ("robustness", "never_worse_pf", "PF never worse than no tracking over any 10 frames", 0.99, ">=", ""),
    ("robustness", "never_worse_smoother", "smoother never worse than no tracking over any 10 frames", 0.99,
     ">=", ""),
    ("robustness", "p95_ratio_smoother_batch", "smoother p95 / batch p95 of per-recording mean tip error", 1.5,
     "<=", ""),
    ("robustness", "reacquired15_pf", "PF re-acquires within 15 frames after a disturbance", 0.95, ">=", ""),
    ("robustness", "reacquired15_smoother", "smoother re-acquires within 15 frames after a disturbance", 0.95,
     ">=", ""),
    ("track", "peak_rss_mb_1080_1800", "peak RSS tracking 1800 frames at 1080x1920", 1024, "<=", "MB"),
    ("stereo", "smoother_tip3d_ratio", "stereo / mono 3-D tip error vs truth, smoother, learned", 0.5, "<=", ""),
    ("stereo", "batch_tip3d_ratio", "stereo / mono 3-D tip error vs truth, batch, learned", 0.5, "<=", ""),
    ("stereo", "smoother_tip2d_left_ratio", "stereo / mono 2-D left tip error, smoother, learned", 0.9, "<=", ""),
    ("stereo", "batch_tip2d_left_ratio", "stereo / mono 2-D left tip error, batch, learned", 0.9, "<=", ""),
    ("stereo_speed", "fps_540_learned_stereo_smoother", "track 540x960 stereo, learned + smoother", 30, ">=",
     "frames/s"),
    ("stereo_speed", "pf_step_ms_1000_stereo", "PF stereo predict+update, 1000 particles, both images", 3, "<=", "ms"),
]


def pin_one_core() -> str:
    try:
        cpu = sorted(os.sched_getaffinity(0))[0]
        os.sched_setaffinity(0, {cpu})
        return f"pinned to CPU {cpu}"
    except (AttributeError, OSError):
        return "not pinned (no sched_setaffinity)"


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}; {os.cpu_count()} logical CPUs; Python {platform.python_version()}; {platform.system()}"


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"
    return str(v)


def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}."))
        elif not isinstance(v, (list, tuple)):
            out[f"{prefix}{k}"] = v
    return out


def _run_of(results: dict, section: str) -> dict:
    """Where and when a section was measured: its own ``_run``, else the file's (older results).
    A target's figure re-run apart from its section names its own in the section's
    ``_run_by_key`` ({key: {"machine", "date"}})."""
    run = results.get(section, {}).get("_run") or {}
    return {k: run.get(k, results.get(f"_{k}", "?")) for k in ("machine", "date", "pinning")}


def render(results: dict) -> str:
    runs = {s: _run_of(results, s) for s in RENDERED if results.get(s)}
    machines = sorted({r["machine"] for r in runs.values()}) or [results.get("_machine", "?")]
    lines = ["# Benchmark results", "",
             f"Written by `python benchmarks/run_all.py` on {results.get('_date', '?')}.", "",
             (f"Machine: {machines[0]}." if len(machines) == 1 else
              f"Machines (each section names its own): {' — '.join(machines)}.") + " Every figure is measured on "
             f"ONE core ({results.get('_pinning', '?')}, one thread for numpy/OpenCV/torch); timings are "
             "medians over repeated runs after warm-up.", ""]
    if results.get("_note"):
        lines += [str(results["_note"]), ""]
    mixed = len(machines) > 1   # timings from different machines do not compare: say whose each is
    lines += ["## Targets", "", "| what | target | measured | met |" + (" measured on |" if mixed else ""),
              "|---|---|---|---|" + ("---|" if mixed else "")]
    for section, key, what, target, op, unit in TARGETS:
        v = _flatten(results.get(section, {})).get(key)
        run = {**_run_of(results, section), **results.get(section, {}).get("_run_by_key", {}).get(key, {})}
        where = f" {run['machine'].split(';')[0]}, {run['date']} |" if mixed else ""
        if v is not None and op == ">=fps":  # the figure is ms per frame
            v, op = 1000.0 / v, ">="
        if v is None:
            lines.append(f"| {what} | {op.replace('fps', '')} {target} {unit} | not measured | – |" + where)
            continue
        if op == "in":
            ok = target[0] <= v <= target[1]
            want = f"in [{target[0]}, {target[1]}]"
        else:   # within rounding: a fraction averaged over seeds (3 x 0.99 -> 0.98999...) meets 0.99
            ok = v >= target - 1e-9 if op == ">=" else v <= target + 1e-9
            want = f"{op} {target} {unit}"
        lines.append(f"| {what} | {want} | {_fmt(v)} {unit} | {'yes' if ok else '**no**'} |" + where)
    for section in RENDERED:
        res = results.get(section)
        if not res:
            continue
        lines += ["", f"## {section}", ""]
        if mixed:
            lines += [f"Measured on {runs[section]['date']}: {runs[section]['machine']}.", ""]
        tables = res.get("tables", {})
        scalars = _flatten({k: v for k, v in res.items()
                            if k not in ("tables", "notes", "plots", "_run", "_run_by_key")})
        if scalars:
            lines += ["| figure | value |", "|---|---|"]
            lines += [f"| {k} | {_fmt(v)} |" for k, v in scalars.items()]
        for title, md in tables.items():
            lines += ["", f"### {title}", "", md.rstrip()]
        for plot in res.get("plots", []):
            lines += ["", f"![{plot}]({plot})"]
        for note in res.get("notes", []):
            lines += ["", note]
    return "\n".join(lines) + "\n"


def plot_scaling(results: dict) -> str | None:
    """scaling.png: PF step time vs particle count, smoother update vs lag (from their sections)."""
    import re

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pf = sorted((int(m.group(1)), v) for k, v in results.get("pf", {}).items()
                if (m := re.fullmatch(r"step_ms_(\d+)", k)))
    sm = sorted((float(m.group(1)), v) for k, v in results.get("smoother", {}).items()
                if (m := re.fullmatch(r"online_lag([0-9.]+)_median_ms", k)))
    if not pf and not sm:
        return None
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    if pf:
        axes[0].loglog([n for n, _ in pf], [v for _, v in pf], "o-")
        axes[0].axhline(3.0, color="grey", ls="--", lw=1, label="3 ms target at 1000")
        axes[0].set(xlabel="particles", ylabel="ms per predict + update", title="particle filter")
        axes[0].legend()
    if sm:
        axes[1].plot([n for n, _ in sm], [v for _, v in sm], "o-")
        axes[1].axhline(3.0, color="grey", ls="--", lw=1, label="3 ms target at 1 s")
        axes[1].set(xlabel="lag (s)", ylabel="median ms per online update", title="fixed-lag smoother")
        axes[1].legend()
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(HERE / "scaling.png", dpi=110)
    plt.close(fig)
    return "scaling.png"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if any(a in ("-h", "--help") for a in argv):
        print(__doc__.strip() + f"\n\nsections: {' '.join(SECTIONS)}")
        return 0
    unknown = [a for a in argv if not (HERE / f"bench_{a}.py").is_file()]
    if unknown:   # nothing run, nothing rewritten
        print(f"run_all.py: no benchmark {', '.join(unknown)} (sections: {' '.join(SECTIONS)})", file=sys.stderr)
        return 2
    wanted = argv or list(SECTIONS)
    store = HERE / "results.json"
    results = json.loads(store.read_text()) if store.exists() else {}
    for section in RENDERED:   # figures kept from an earlier run keep that run's machine and date
        if isinstance(results.get(section), dict):
            results[section].setdefault("_run", _run_of(results, section))
    results["_pinning"] = pin_one_core()
    results["_machine"] = machine()
    results["_date"] = datetime.date.today().isoformat()
    results["_note"] = os.environ.get("GRAPHTRACK_BENCH_NOTE", "")  # a caveat about this run, if any
    sys.path.insert(0, str(HERE))
    for name in wanted:
        module = importlib.import_module(f"bench_{name}")
        t = time.perf_counter()
        print(f"== {name}", flush=True)
        fresh: dict = {}
        module.run(fresh)
        if name not in fresh:  # a benchmark that filled the dict flat: file it under its section
            fresh = {name: fresh}
        fresh[name]["_run"] = {k: results[f"_{k}"] for k in ("machine", "date", "pinning")}
        results.update(fresh)
        print(f"   {name}: {time.perf_counter() - t:.0f} s", flush=True)
        store.write_text(json.dumps(results, indent=1, default=float))  # keep what is done
        (HERE / "RESULTS.md").write_text(render(results))
    plot = plot_scaling(results)
    if plot:
        results.setdefault("scaling", {})["plots"] = [plot]
    (HERE / "RESULTS.md").write_text(render(results))
    store.write_text(json.dumps(results, indent=1, default=float))
    print(f"wrote {HERE / 'RESULTS.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
