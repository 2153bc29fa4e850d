"""The synthetic observation world (graphtrack.sim.synthetic) as the robustness tests
use it: a scene whose prior E0 is off the truth by a random left error of given
size, joints per frame, and noisy observations of the true geometry."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphtrack.sim import synthetic as syn


@dataclass
class World:
    scene: syn.Scene
    E_true: np.ndarray
    x_true: np.ndarray

    @property
    def ctx(self):
        return self.scene.ctx

    def joints(self, t: int) -> np.ndarray:
        return syn.joint_trajectory(1, start=t)[0]

    def observation(self, q, model, rng, pixel_noise=1.0, outliers=0.05, marker_noise=0.0):
        return syn.observe(self.scene, q, self.E_true, rng, pixel_noise=pixel_noise, outliers=outliers,
                           marker_noise=marker_noise).observation(model)


def make_world(seed: int, b_mm: float, w_deg: float) -> World:
    """E_true = Exp(x_true) . E0, x_true of magnitudes b_mm / w_deg in random directions (seed)."""
    scene = syn.make_scene()
    x = syn.random_handeye_error(np.random.default_rng(seed), b_mm, w_deg)
    return World(scene, scene.true_E(x), x)
