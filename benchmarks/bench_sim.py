"""Simulator throughput: frames/s at 540x960 for both scenes, rendering AND writing a bag.

    python benchmarks/bench_sim.py            # prints the figures
    run(results)                              # fills results["sim"] for a benchmark runner

One core: OpenCV is limited to one thread (numpy's element-wise work is
single-threaded). Each repeat simulates a fresh recording of FRAMES frames
into a temporary folder (uncompressed bag, the default); frames/s counts the
frames only (setup time - ray table, textures, trajectory - is reported
separately). The figure is the median over REPEATS repeats after one warm-up.
"""
from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

FRAMES = 60
REPEATS = 3
SIZE = (540, 960)
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # runnable from a checkout


def _one(scene: str, seed: int, tmp: Path) -> tuple[float, float]:
    from graphtrack.io.bag_write import write_bag
    from graphtrack.sim.simulate import Simulation

    t0 = time.perf_counter()
    sim = Simulation(scene, FRAMES, seed, SIZE)
    t1 = time.perf_counter()
    write_bag(tmp / f"{scene}-{seed}.bag", sim.frames())
    t2 = time.perf_counter()
    (tmp / f"{scene}-{seed}.bag").unlink()
    return FRAMES / (t2 - t1), t1 - t0


def run(results: dict) -> dict:
    from graphtrack.threads import limit_threads

    limit_threads(1)
    out = results.setdefault("sim", {})
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for scene in ("structured", "tissue"):
            _one(scene, 100, tmp)  # warm-up
            runs = [_one(scene, 101 + r, tmp) for r in range(REPEATS)]
            out[f"{scene}_fps"] = statistics.median(r[0] for r in runs)
            out[f"{scene}_setup_s"] = statistics.median(r[1] for r in runs)
    out["size"] = f"{SIZE[0]}x{SIZE[1]}"
    out["frames"] = FRAMES
    return results


if __name__ == "__main__":
    res = run({})["sim"]
    for scene in ("structured", "tissue"):
        print(f"{scene:10s} {res[f'{scene}_fps']:6.1f} frames/s (render + bag write, {res['size']}, 1 thread), "
              f"setup {res[f'{scene}_setup_s']:.2f} s")
