"""Synthetic dVRK recordings with exact ground truth (``graphtrack simulate``).

    simulate(out_dir, scene="structured"|"tissue", frames=N, seed=S, size=(H, W),
             compressed=False, form="bag"|"folder", randomize=False, progress=True) -> Path
    cached_recording(scene, frames, seed, size) -> Path    # simulated once, then re-used

See :mod:`graphtrack.sim.simulate` for the definition of the true E_t in truth.csv.
"""
from graphtrack.sim.simulate import Simulation, cache_dir, cached_recording, simulate

__all__ = ["simulate", "cached_recording", "cache_dir", "Simulation"]
