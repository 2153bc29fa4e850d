"""benchmarks/run_all.py: a subset re-run keeps the other sections' machine and date, and
RESULTS.md then names each section's and each target's machine (timings of two machines
do not compare)."""
from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import run_all  # noqa: E402


def _results(machine: str) -> dict:
    return {"_machine": machine, "_date": "2026-01-01", "_pinning": "pinned to CPU 0",
            "sim": {"structured_fps": 40.0, "tissue_fps": 41.0},
            "pf": {"step_ms_1000": 2.0}}


def test_one_machine_renders_as_before():
    md = run_all.render(_results("AMD EPYC; 2 logical CPUs"))
    assert "Machine: AMD EPYC; 2 logical CPUs. Every figure" in md
    assert "| what | target | measured | met |\n" in md and "measured on |" not in md
    assert "_run" not in md


def test_a_section_rerun_elsewhere_keeps_the_others_machine(tmp_path, monkeypatch):
    bench = tmp_path / "bench"
    bench.mkdir()
    (bench / "results.json").write_text(json.dumps(_results("AMD EPYC; 2 logical CPUs")))
    (bench / "bench_pf.py").write_text("def run(results):\n    results['pf'] = {'step_ms_1000': 5.0}\n")
    monkeypatch.setattr(run_all, "HERE", bench)
    monkeypatch.setattr(run_all, "machine", lambda: "Intel Xeon; 2 logical CPUs")
    monkeypatch.setattr(run_all, "pin_one_core", lambda: "pinned to CPU 0")
    monkeypatch.setattr(sys, "path", [str(bench)] + sys.path)
    sys.modules.pop("bench_pf", None)
    assert run_all.main(["pf"]) == 0
    sys.modules.pop("bench_pf", None)
    stored = json.loads((bench / "results.json").read_text())
    assert stored["sim"]["_run"]["machine"] == "AMD EPYC; 2 logical CPUs"
    assert stored["sim"]["_run"]["date"] == "2026-01-01"
    assert stored["pf"]["_run"]["machine"] == "Intel Xeon; 2 logical CPUs"
    md = (bench / "RESULTS.md").read_text()
    assert "Machines (each section names its own): AMD EPYC; 2 logical CPUs — Intel Xeon; 2 logical CPUs." in md
    rows = {line.split(" | ")[0].lstrip("| "): line for line in md.splitlines() if line.startswith("| ")}
    assert rows["simulator, 540x960 structured, render + write"].endswith("| 40 frames/s | yes | AMD EPYC, 2026-01-01 |")
    pf = rows["PF predict+update, 1000 particles, ~500 px, 4 markers, shaft end"]
    assert pf.endswith("| 5 ms | **no** | Intel Xeon, " + stored["pf"]["_run"]["date"] + " |")
    assert "Measured on 2026-01-01: AMD EPYC; 2 logical CPUs." in md


def test_a_target_rerun_apart_from_its_section_names_its_own_machine():
    """_run_by_key: the figure's row in the targets table names where it was re-run; the
    section's other targets keep the section's machine, and the key is not a figure."""
    res = _results("AMD EPYC; 2 logical CPUs")
    res["sim"]["_run"] = {"machine": "Intel Xeon; 2 logical CPUs", "date": "2026-01-02"}
    res["sim"]["_run_by_key"] = {"tissue_fps": {"machine": "AMD EPYC; 2 logical CPUs", "date": "2026-01-03"}}
    md = run_all.render(res)
    rows = {line.split(" | ")[0].lstrip("| "): line for line in md.splitlines() if line.startswith("| ")}
    assert rows["simulator, 540x960 structured, render + write"].endswith("| Intel Xeon, 2026-01-02 |")
    assert rows["simulator, 540x960 tissue, render + write"].endswith("| AMD EPYC, 2026-01-03 |")
    assert "_run_by_key" not in md
