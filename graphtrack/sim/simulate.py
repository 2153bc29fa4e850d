"""Synthetic dVRK recordings with exact ground truth (the sequence format + truth.csv).

Ground truth. With E_he the TRUE hand-eye (camera-from-base), q_t the TRUE
joints that drive the renderer and q~_t the noisy READINGS written to the bag,

    camera_T_link4_true(t) = E_he . base_T_link4(q_t)
    E_t = camera_T_link4_true(t) . base_T_link4(q~_t)^-1

i.e. E_t is the lumped error that makes the kinematics of the READINGS put
the shaft link (link 4, hence the shaft's limb lines and markers) exactly
where it is: E_t . base_T_link4(q~_t) = camera_T_link4_true(t). It absorbs
the hand-eye error and the biases and noise of joints 1-3; the (small) noise
of the wrist joints 4-6 and the jaw is NOT absorbed, so E_t . FK(q~_t) places
the jaws slightly off. truth.csv holds E_t (translation m, quaternion x, y, z, w)
and the TRUE tip: robot.tool_tip through E_he . base_T_link7(q_t), projected
with distortion into the RAW image (tip_u, tip_v; NaN when behind the camera).
handeye.yaml holds the NOMINAL Delta . E_he (Delta: 2-5 mm, 1-3 deg).
labels.csv: the true tip + N(0, 1.2 px) labelling noise, omitted when the
tip is outside the image, behind a tissue flap, or hidden by the shaft or
wrist (> 3 mm in front of it on its pixel). The other jaw crossing in front
does not count: the jaws are thin and a labeller marks the tip through them.
Stamps: t0 + i / 30 s.
"""
from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphtrack.errors import InputError
from graphtrack.io.outdir import writable_dir
from graphtrack.geometry.camera import Calibration, save_calibration
from graphtrack.geometry.se3 import matrix_to_quaternion, transform_points
from graphtrack.robot.description import save_robot_json
from graphtrack.robot.kinematics import link_transforms
from graphtrack.robot.psm import psm_large_needle_driver
from graphtrack.sim import motion
from graphtrack.sim.scene import SCENES, make_scene, tool_primitives

FPS = 30.0
T0 = 1_600_000_000.0
MIN_SIZE = 64
TRUTH_COLUMNS = "frame,stamp,tx,ty,tz,qx,qy,qz,qw,tip_u,tip_v,ms"
LABEL_NOISE_PX = 1.2


@dataclass
class SimFrame:
    """What the writers take: stamp (s), image (BGR uint8), joints (DH readings), jaw."""

    index: int
    stamp: float
    image: np.ndarray
    joints: np.ndarray
    jaw: float


def check_args(scene: str, frames: int, size) -> tuple[int, int]:
    if scene not in SCENES:
        raise InputError(f"unknown scene {scene!r}; choose one of {', '.join(SCENES)}")
    if int(frames) != frames or frames <= 0:
        raise InputError(f"--frames must be a positive integer, got {frames}")
    try:
        H, W = (int(v) for v in size)
    except (TypeError, ValueError):
        raise InputError(f"size must be (height, width), got {size!r}") from None
    if H < MIN_SIZE or W < MIN_SIZE:
        raise InputError(f"image size {H}x{W} is too small for the tool: at least {MIN_SIZE} px each side")
    if H > 4096 or W > 4096:
        raise InputError(f"image size {H}x{W} is too large (at most 4096 px each side)")
    return H, W


class Simulation:
    """A planned recording: scene, true and read joints, truth; frames rendered on demand."""

    def __init__(self, scene: str = "structured", frames: int = 300, seed: int = 0, size=(540, 960),
                 randomize: bool = False, noise_free: bool = False, antialias: bool = True):
        H, W = check_args(scene, frames, size)
        self.robot = psm_large_needle_driver()
        ss = np.random.SeedSequence([int(seed), SCENES.index(scene), int(randomize), int(noise_free)])
        r_scene, r_pose, r_motion, r_read, r_frame, r_label = (np.random.default_rng(s) for s in ss.spawn(6))
        self.rng_frame, self.rng_label = r_frame, r_label
        self.scene = make_scene(scene, (H, W), r_scene, randomize, noise_free)
        self.scene.setup_renderer(self.robot, antialias)
        cam = self.scene.camera
        self.E_he = motion.look_at_workspace(
            self.robot, motion.Q0, self.scene.distance, r_pose.uniform(58, 72), r_pose.uniform(-np.pi, np.pi),
            r_pose.choice([-1, 1]) * r_pose.uniform(25, 70) - 90, r_pose.uniform(0.08, 0.16) * W, cam.fx)
        self.delta = np.eye(4) if noise_free else motion.handeye_error(r_pose)
        self.E_nominal = self.delta @ self.E_he
        self.q_true = motion.true_trajectory(self.robot, cam, self.E_he, motion.Q0, frames, FPS, r_motion)
        self.q_read = motion.readings(r_read, self.q_true, FPS, noise_free)
        self.E_t = motion.lumped_error(self.robot, self.E_he, self.q_true, self.q_read)
        self.L_true = self.E_he @ link_transforms(self.robot, self.q_true)     # (N, links, 4, 4)
        tip = transform_points(self.L_true[:, self.robot.tool_tip.link], np.asarray(self.robot.tool_tip.position))
        front = tip[:, 2] > 1e-6
        self.tip_cam = tip
        self.tip_uv = np.where(front[:, None], cam.project_raw(np.where(front[:, None], tip, 1.0)), np.nan)
        self.scene.plan_occlusions(r_scene, self.L_true)
        self.n = int(frames)

    @property
    def camera(self):
        return self.scene.camera

    def render(self, i: int):
        """Frame i -> (image, tip visible?)."""
        prims = tool_primitives(self.L_true[i])
        uv = self.tip_uv[i]
        probe = uv if np.all(np.isfinite(uv)) else None
        img, (depth, prim), covered = self.scene.compose(prims, i, self.rng_frame, probe)
        H, W = img.shape[:2]
        inside = probe is not None and 0 <= uv[0] <= W - 1 and 0 <= uv[1] <= H - 1
        behind = depth < self.tip_cam[i, 2] - 0.003 and (prim is None or prim.material != "jaw")
        visible = inside and not covered and not behind
        return img, bool(visible)

    def frames(self, truth_file=None, labels: dict | None = None):
        """Yield SimFrame 0..n-1, writing truth rows and collecting labels on the way."""
        for i in range(self.n):
            img, visible = self.render(i)
            stamp = T0 + i / FPS
            if truth_file is not None:
                E = self.E_t[i]
                q = matrix_to_quaternion(E[:3, :3])
                vals = [stamp, *E[:3, 3], *q, *self.tip_uv[i]]
                truth_file.write(f"{i}," + ",".join(repr(float(v)) for v in vals) + ",\n")
            if labels is not None and visible:
                labels[i] = self.tip_uv[i] + self.rng_label.normal(0, LABEL_NOISE_PX, 2)
            yield SimFrame(i, stamp, img, self.q_read[i, :6].copy(), float(self.q_read[i, 6]))


def _prepare_out(out: Path) -> None:
    writable_dir(out, "the recording there")
    for old in list(out.glob("*.bag")) + [out / "frames", out / "joints.csv", out / "labels.csv"]:
        if old.is_dir():
            shutil.rmtree(old)
        elif old.exists():
            old.unlink()


def simulate(out_dir, scene: str = "structured", frames: int = 300, seed: int = 0, size=(540, 960),
             compressed: bool = False, form: str = "bag", randomize: bool = False, progress: bool = True,
             noise_free: bool = False) -> Path:
    """Write a simulated recording into ``out_dir`` (sequence format + truth.csv) and return it.

    scene: "structured" | "tissue"; frames > 0; size = (H, W) px; form: "bag"
    (one ROS 1 bag ``recording.bag``; ``compressed`` -> PNG CompressedImage) or
    "folder" (frames/ + joints.csv). ``noise_free``: no hand-eye error, no
    joint noise, no sensor noise/blur/flap (for geometry tests).
    Frames are rendered and written one at a time.
    """
    from graphtrack.io.handeye import save_handeye
    from graphtrack.io.labels import write_labels

    if form not in ("bag", "folder"):
        raise InputError(f"unknown form {form!r}; choose bag or folder")
    sim = Simulation(scene, frames, seed, size, randomize, noise_free)
    out = Path(out_dir)
    _prepare_out(out)
    save_robot_json(out / "robot.json", sim.robot)
    save_calibration(out / "camera_calibration.yaml", Calibration(sim.camera))
    save_handeye(out / "handeye.yaml", sim.E_nominal)
    labels: dict = {}
    with (out / "truth.csv").open("w", newline="") as tf:
        tf.write(TRUTH_COLUMNS + "\n")
        it = sim.frames(tf, labels)
        if progress:
            from tqdm import tqdm

            it = tqdm(it, total=sim.n, desc=f"simulate {scene}", unit="frame")
        if form == "bag":
            from graphtrack.io.bag_write import write_bag

            write_bag(out / "recording.bag", it, compressed=compressed, image_format="png")
        else:
            from graphtrack.io.folder import write_folder

            write_folder(out, it)
    write_labels(out / "labels.csv", labels)
    return out


def cache_dir() -> Path:
    """$GRAPHTRACK_CACHE/sim, else ~/.cache/graphtrack/sim."""
    root = os.environ.get("GRAPHTRACK_CACHE")
    return (Path(root) if root else Path.home() / ".cache" / "graphtrack") / "sim"


#: bumped when a cached recording's content changes (2: robot.json carries the markers' disc radius)
CACHE_VERSION = 2


def cached_recording(scene: str = "structured", frames: int = 300, seed: int = 0, size=(540, 960),
                     progress: bool = True) -> Path:
    """A simulated recording in the cache, simulated on first use (``.complete`` marks it done)."""
    H, W = check_args(scene, frames, size)
    final = cache_dir() / f"{scene}-{int(frames)}-{int(seed)}-{H}x{W}-v{CACHE_VERSION}"
    if (final / ".complete").is_file():
        return final
    tmp = final.with_name(final.name + f".tmp-{os.getpid()}")
    if tmp.exists():
        shutil.rmtree(tmp)
    simulate(tmp, scene, frames, seed, (H, W), progress=progress)
    (tmp / ".complete").write_text("ok\n")
    if final.exists() and not (final / ".complete").is_file():
        shutil.rmtree(final)
    try:
        os.replace(tmp, final)
    except OSError:  # another process finished first
        shutil.rmtree(tmp, ignore_errors=True)
    return final
