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
and the TRUE tip: robot.tool_tip through E_he . base_T_link7(q_t), in the left
camera frame (tip_x, tip_y, tip_z, m) and projected with distortion into the RAW
image (tip_u, tip_v; NaN when behind the camera); ms is empty.
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
from tqdm import tqdm

from graphtrack.errors import InputError, check_seed, is_number
from graphtrack.geometry.camera import Calibration, save_calibration
from graphtrack.geometry.se3 import matrix_to_bw, matrix_to_quaternion, transform_points
from graphtrack.io.bag_write import write_bag
from graphtrack.io.folder import write_folder
from graphtrack.io.handeye import save_handeye
from graphtrack.io.labels import write_labels
from graphtrack.io.outdir import writable_dir
from graphtrack.robot.description import save_robot_json
from graphtrack.robot.kinematics import link_transforms
from graphtrack.robot.psm import psm_large_needle_driver
from graphtrack.sim import motion, occluders
from graphtrack.sim import stereo as sim_stereo
from graphtrack.sim.effects import draw_effects
from graphtrack.sim.scenario import draw_events, intervals, write_scenario
from graphtrack.sim.scene import SCENES, make_scene, tool_primitives

FPS = 30.0
T0 = 1_600_000_000.0
MIN_SIZE = 64
TRUTH_COLUMNS = "frame,stamp,tx,ty,tz,qx,qy,qz,qw,tip_u,tip_v,ms,tip_x,tip_y,tip_z"
LABEL_NOISE_PX = 1.2
#: randomized hand-eye error: |b| ~ U(0, 10) mm, |w| ~ U(0, 5) deg
HANDEYE_RANDOM = ((0.0, 0.010), (0.0, 5.0))


@dataclass
class SimFrame:
    """What the writers take: stamp (s), image (BGR uint8), joints (DH readings), jaw,
    image_right (BGR uint8, stereo only)."""

    index: int
    stamp: float
    image: np.ndarray
    joints: np.ndarray
    jaw: float
    image_right: np.ndarray | None = None


#: the longest simulated recording (frames)
MAX_FRAMES = 1_000_000


def check_args(scene: str, frames: int, size) -> tuple[int, int]:
    if scene not in SCENES:
        raise InputError(f"unknown scene {scene!r}; choose one of {', '.join(SCENES)}")
    if int(frames) != frames or not 0 < frames <= MAX_FRAMES:
        raise InputError(f"--frames must be an integer in 1..{MAX_FRAMES} (9 hours at 30 frames/s; the "
                         f"simulation holds every frame's poses in memory), got {frames}")
    try:
        H, W = (int(v) for v in size)
    except (TypeError, ValueError):
        raise InputError(f"size must be (height, width), got {size!r}") from None
    if H < MIN_SIZE or W < MIN_SIZE:
        raise InputError(f"image size {H}x{W} is too small for the tool: at least {MIN_SIZE} px each side")
    if H > 4096 or W > 4096:
        raise InputError(f"image size {H}x{W} is too large (at most 4096 px each side)")
    return H, W


def check_draw_overrides(shaft_angle, handeye_error) -> None:
    """InputError for a shaft angle that is not a finite number of degrees, or a hand-eye
    error that is not (|b| m in [0, 0.1], |w| rad in [0, 30 deg])."""
    if shaft_angle is not None and not is_number(shaft_angle):
        raise InputError(f"shaft angle must be a finite number of degrees, got {shaft_angle!r}")
    if handeye_error is None:
        return
    try:
        b, w = (float(v) for v in handeye_error)
    except (TypeError, ValueError):
        raise InputError(f"hand-eye error must be (|b| m, |w| rad), got {handeye_error!r}") from None
    if not (0.0 <= b <= 0.1 and 0.0 <= w <= np.radians(30.0)):
        raise InputError(f"hand-eye error must be 0-100 mm and 0-30 deg, got {b * 1e3:g} mm, {np.degrees(w):g} deg")


class Simulation:
    """A planned recording: scene, true and read joints, truth; frames rendered on demand.

    stereo: also a right camera (sim/stereo.py; right-only random streams, so the
    left images, joints, truth and labels are the same with and without it).
    randomize: the scene's look is randomized (sim/scene.py) and so are the
    hand-eye error (|b| 0-10 mm, |w| 0-5 deg), an out-of-view excursion,
    occlusions and image effects (``self.scenario``: what was drawn).
    shaft_angle (deg): the image direction the shaft enters from, counter-clockwise from
    the image's right (0: from the right edge, 90: from the top, 180: from the left); None:
    drawn, 20-65 or 115-160 deg (from an upper edge). handeye_error (|b| m, |w| rad): the
    hand-eye error's size (its directions drawn); None: drawn as above. For either, the
    seed's other draws are the same.
    """

    def __init__(self, scene: str = "structured", frames: int = 300, seed: int = 0, size=(540, 960),
                 randomize: bool = False, noise_free: bool = False, antialias: bool = True,
                 stereo: bool = False, shaft_angle: float | None = None,
                 handeye_error: tuple[float, float] | None = None):
        H, W = check_args(scene, frames, size)
        check_draw_overrides(shaft_angle, handeye_error)
        self.robot = psm_large_needle_driver()
        ss = np.random.SeedSequence([int(seed), SCENES.index(scene), int(randomize), int(noise_free)])
        (r_scene, r_pose, r_motion, r_read, r_frame, r_label,
         r_right, r_label_right, r_events) = (np.random.default_rng(s) for s in ss.spawn(9))
        self.rng_frame, self.rng_label, self.rng_label_right = r_frame, r_label, r_label_right
        self.randomize, self.n = bool(randomize), int(frames)
        self.scene = make_scene(scene, (H, W), r_scene, randomize, noise_free)
        self.scene.setup_renderer(self.robot, antialias)
        cam = self.scene.camera
        view, azimuth = r_pose.uniform(58, 72), r_pose.uniform(-np.pi, np.pi)
        entry = r_pose.choice([-1, 1]) * r_pose.uniform(25, 70) - 90   # y-down image angle towards the entry
        if shaft_angle is not None:
            entry = -float(shaft_angle)
        self.E_he = motion.look_at_workspace(self.robot, motion.Q0, self.scene.distance, view, azimuth, entry,
                                             r_pose.uniform(0.08, 0.16) * W, cam.fx)
        if noise_free:
            self.delta = np.eye(4)
        elif handeye_error is not None:   # the same draws, sizes fixed
            b, w = (float(v) for v in handeye_error)
            self.delta = motion.handeye_error(r_pose, (b, b), (np.degrees(w),) * 2)
        else:
            self.delta = (motion.handeye_error(r_pose, HANDEYE_RANDOM[0], HANDEYE_RANDOM[1]) if randomize
                          else motion.handeye_error(r_pose))
        self.E_nominal = self.delta @ self.E_he
        self.q_true = motion.true_trajectory(self.robot, cam, self.E_he, motion.Q0, frames, FPS, r_motion)
        events = draw_events(r_events, self.n) if randomize and not noise_free else []
        self.excursion = self._excursion(events)
        self.q_read = motion.readings(r_read, self.q_true, FPS, noise_free)
        self.E_t = motion.lumped_error(self.robot, self.E_he, self.q_true, self.q_read)
        self.L_true = self.E_he @ link_transforms(self.robot, self.q_true)     # (N, links, 4, 4)
        tip = transform_points(self.L_true[:, self.robot.tool_tip.link], np.asarray(self.robot.tool_tip.position))
        self.tip_cam = tip
        self.tip_uv = _project_tip(cam, tip)
        self.scene.plan_occlusions(r_scene, self.L_true)
        if events:
            wins = [(s, s + n, x["target"]) for k, s, n, x in events if k == "occlusion"]
            self.scene.occlusions = occluders.plan(r_events, wins, self.L_true, cam)
        if randomize and not noise_free:
            self.scene.effects = draw_effects(r_events, self.n, H, W)
        self.view = self.scene.left_view(r_frame)
        self.right = None
        if stereo:
            rnd = r_right if randomize else None
            base = r_right.uniform(0.004, 0.006) if randomize else sim_stereo.BASELINE
            verg = np.radians(r_right.uniform(0.0, 3.0)) if randomize else sim_stereo.VERGENCE
            self.R, self.T = sim_stereo.rig(base, verg)
            cam_r = sim_stereo.right_camera(cam, rnd)
            self.right = self.scene.add_view(cam_r, sim_stereo.to_right(self.R, self.T), r_right, antialias)
            self.tip_cam_right = tip @ self.R.T + self.T
            self.tip_uv_right = _project_tip(cam_r, self.tip_cam_right)

    def _excursion(self, events) -> dict | None:
        for kind, s, n, x in events:
            if kind == "excursion":
                q, delta = motion.excursion(self.robot, self.camera, self.E_he, self.q_true, s, x["ramp"], x["hold"])
                self.q_true = q
                return {"start": s, "end": s + n, "ramp": x["ramp"], "hold": x["hold"], "applied": delta is not None,
                        "retraction_m": None if delta is None else float(delta[2]),
                        "yaw_swing_rad": None if delta is None else float(delta[0])}
        return None

    @property
    def camera(self):
        return self.scene.camera

    @property
    def calibration(self) -> Calibration:
        """The recording's camera_calibration.yaml content (right camera when stereo)."""
        if self.right is None:
            return Calibration(self.camera)
        return Calibration(self.camera, self.right.camera, self.R, self.T)

    def render(self, i: int, right: bool = False):
        """Frame i of the left (or right) camera -> (image, tool tip visible?)."""
        view = self.right if right else self.view
        to = view.to_view
        L = self.L_true[i] if to is None else to @ self.L_true[i]
        uvs, tip = (self.tip_uv, self.tip_cam) if to is None else (self.tip_uv_right, self.tip_cam_right)
        uv = uvs[i]
        probe = uv if np.all(np.isfinite(uv)) else None
        vel = None
        if self.scene.effects is not None:
            j = i - 1 if i > 0 else min(i + 1, self.n - 1)
            vel = (uv - uvs[j]) * (1 if i > 0 else -1)
        img, (depth, prim), covered = self.scene.compose(view, tool_primitives(L), i, probe, vel)
        H, W = img.shape[:2]
        inside = probe is not None and 0 <= uv[0] <= W - 1 and 0 <= uv[1] <= H - 1
        behind = depth < tip[i, 2] - 0.003 and (prim is None or prim.material != "jaw")
        visible = inside and not covered and not behind
        return img, bool(visible)

    def frames(self, truth_file=None, labels: dict | None = None, labels_right: dict | None = None):
        """Yield SimFrame 0..n-1 (image_right set for stereo), writing truth rows and
        collecting labels on the way."""
        for i in range(self.n):
            img, visible = self.render(i)
            stamp = T0 + i / FPS
            if truth_file is not None:
                E = self.E_t[i]
                q = matrix_to_quaternion(E[:3, :3])
                vals = [stamp, *E[:3, 3], *q, *self.tip_uv[i]]
                tip = ",".join(repr(float(v)) for v in self.tip_cam[i])
                truth_file.write(f"{i}," + ",".join(repr(float(v)) for v in vals) + f",,{tip}\n")
            if labels is not None and visible:
                labels[i] = self.tip_uv[i] + self.rng_label.normal(0, LABEL_NOISE_PX, 2)
            img_r = None
            if self.right is not None:
                img_r, vis_r = self.render(i, right=True)
                if labels_right is not None and vis_r:
                    labels_right[i] = self.tip_uv_right[i] + self.rng_label_right.normal(0, LABEL_NOISE_PX, 2)
            yield SimFrame(i, stamp, img, self.q_read[i, :6].copy(), float(self.q_read[i, 6]), img_r)

    def scenario(self) -> dict:
        """What a randomized recording drew (scenario.json; see sim/scenario.py)."""
        bw = matrix_to_bw(self.delta)
        cam = self.camera
        tip_in = cam.in_image(self.tip_cam)
        shaft_in = np.array([len(occluders.shaft_samples(self.L_true[i, 4], cam)[0]) > 0 for i in range(self.n)])
        fx = self.scene.effects
        return {
            "frames": self.n, "fps": FPS,
            "handeye_error": {"translation_mm": float(np.linalg.norm(bw[:3]) * 1000),
                              "rotation_deg": float(np.degrees(np.linalg.norm(bw[3:]))),
                              "bw": bw, "delta": self.delta},
            "occlusions": [{"kind": o.kind, "start": o.start, "end": o.end, "target_coverage": o.target,
                            "coverage": o.coverage, "mean_coverage": float(np.nanmean(o.coverage)),
                            "max_coverage": float(np.nanmax(o.coverage))} for o in self.scene.occlusions],
            "out_of_view": {"excursion": self.excursion, "tip_out": intervals(~tip_in),
                            "shaft_out": intervals(~shaft_in)},
            "effects": {**(fx.info if fx is not None else {}),
                        "sensor_noise": {"on": self.scene.noise is not None},
                        "optical_blur_sigma_px": self.scene.blur,
                        "vignetting_strength": self.scene.vig_strength},
            "look": {"fx_px": cam.fx, "distortion": cam.dist, "light": self.scene.light,
                     "falloff": self.scene.falloff, "shaft_material": vars(self.scene.materials["shaft"])},
        }


def _project_tip(cam, tip: np.ndarray) -> np.ndarray:
    """Raw pixels of camera-frame points; NaN behind the camera."""
    front = tip[:, 2] > 1e-6
    return np.where(front[:, None], cam.project_raw(np.where(front[:, None], tip, 1.0)), np.nan)


#: what a recording folder may hold that simulate replaces
RECORDING_FILES = ("robot.json", "camera_calibration.yaml", "handeye.yaml", "joints.csv", "frames", "frames_right",
                   "video.mp4", "labels.csv", "labels_right.csv")


def _prepare_out(out: Path, overwrite: bool = False) -> None:
    """Make ``out`` ready for a simulated recording. A folder holding a recording that was
    not simulated (recording files, or a bag, and no truth.csv, which simulate always
    writes) is refused unless ``overwrite``: it may be a lab's own recording."""
    found = [n for n in RECORDING_FILES if (out / n).exists()] + [p.name for p in out.glob("*.bag")] \
        if out.is_dir() else []
    if found and not (out / "truth.csv").is_file() and not overwrite:
        raise InputError(f"{out}: holds a recording that was not simulated ({', '.join(found[:4])}"
                         f"{', ...' if len(found) > 4 else ''}); simulate would replace it: choose another "
                         "folder, or --overwrite")
    writable_dir(out, "the recording there")
    for old in list(out.glob("*.bag")) + [out / n for n in ("frames", "frames_right", "joints.csv", "labels.csv",
                                                             "labels_right.csv", "scenario.json")]:
        if old.is_dir():
            shutil.rmtree(old)
        elif old.exists():
            old.unlink()


def simulate(out_dir, scene: str = "structured", frames: int = 300, seed: int = 0, size=(540, 960),
             compressed: bool = False, form: str = "bag", randomize: bool = False, progress: bool = True,
             noise_free: bool = False, stereo: bool = False, image_format: str = "png",
             overwrite: bool = False, shaft_angle: float | None = None,
             handeye_error: tuple[float, float] | None = None) -> Path:
    """Write a simulated recording into ``out_dir`` (sequence format + truth.csv) and return it.

    scene: "structured" | "tissue"; frames > 0; size = (H, W) px; form: "bag"
    (one ROS 1 bag ``recording.bag``; ``compressed`` -> CompressedImage) or
    "folder" (frames/ + joints.csv). image_format: "png" (lossless) or "jpeg" (OpenCV's
    quality 95, a tenth of the size) for the folder's files and compressed bag images. ``noise_free``: no hand-eye error, no
    joint noise, no sensor noise/blur/flap (for geometry tests). ``stereo``: also
    the right images (``/stereo/right/image[/compressed]`` or frames_right/), K2, D2,
    R, T in camera_calibration.yaml and labels_right.csv. ``randomize``: also
    scenario.json (what was drawn; sim/scenario.py). ``out_dir`` holding a recording
    that was not simulated is refused unless ``overwrite`` (one simulated before is
    replaced). Frames are rendered and written one at a time. ``shaft_angle`` (deg): the
    direction the shaft enters the image from; ``handeye_error`` (|b| m, |w| rad): the size of
    handeye.yaml's error (:class:`Simulation`); None: drawn.
    """
    if image_format not in ("png", "jpeg"):
        raise InputError(f"unknown image format {image_format!r}; choose png or jpeg")
    if form not in ("bag", "folder"):
        raise InputError(f"unknown form {form!r}; choose bag or folder")
    check_seed(seed)
    sim = Simulation(scene, frames, seed, size, randomize, noise_free, stereo=stereo, shaft_angle=shaft_angle,
                     handeye_error=handeye_error)
    out = Path(out_dir)
    _prepare_out(out, overwrite)
    save_robot_json(out / "robot.json", sim.robot)
    save_calibration(out / "camera_calibration.yaml", sim.calibration)
    save_handeye(out / "handeye.yaml", sim.E_nominal)
    labels: dict = {}
    labels_right: dict | None = {} if stereo else None
    with (out / "truth.csv").open("w", newline="") as tf:
        tf.write(TRUTH_COLUMNS + "\n")
        it = sim.frames(tf, labels, labels_right)
        if progress:
            it = tqdm(it, total=sim.n, desc=f"simulate {scene}", unit="frame")
        if form == "bag":
            write_bag(out / "recording.bag", it, compressed=compressed, image_format=image_format)
        else:
            write_folder(out, it, image_ext="jpg" if image_format == "jpeg" else "png")
    write_labels(out / "labels.csv", labels)
    if labels_right is not None:
        write_labels(out / "labels_right.csv", labels_right)
    if randomize:
        write_scenario(out / "scenario.json", sim.scenario())
    return out


def cache_dir() -> Path:
    """$GRAPHTRACK_CACHE/sim, else ~/.cache/graphtrack/sim."""
    root = os.environ.get("GRAPHTRACK_CACHE")
    return (Path(root) if root else Path.home() / ".cache" / "graphtrack") / "sim"


#: bumped when a simulated recording's content changes, so that a recording kept from an
#: older simulator is simulated again (2: robot.json carries the markers' disc radius;
#: 3: truth.csv carries the exact tip in the camera frame, tip_x, tip_y, tip_z)
CACHE_VERSION = 3
#: bumped when a randomized recording's content or scenario.json changes (2: a shaft or tip
#: sample counts as in view only when the camera images it, Camera.in_image)
RANDOMIZED_VERSION = 2


def simulated_once(path, **simulate_args) -> Path:
    """``path`` holding :func:`simulate` (``simulate_args``)'s recording: simulated on first
    use, re-used after (its ``.complete`` marker holds CACHE_VERSION), simulated again when
    an older simulator wrote it. Simulated into a temporary sibling and renamed, so that
    an interrupted run or a concurrent one never leaves half a recording at ``path``."""
    final = Path(path)
    done, version = final / ".complete", f"v{CACHE_VERSION}\n"
    if done.is_file() and done.read_text() == version:
        return final
    tmp = final.with_name(final.name + f".tmp-{os.getpid()}")
    if tmp.exists():
        shutil.rmtree(tmp)
    simulate(tmp, **simulate_args)
    (tmp / ".complete").write_text(version)
    if final.exists() and not (done.is_file() and done.read_text() == version):
        shutil.rmtree(final)
    try:
        os.replace(tmp, final)
    except OSError:  # another process finished first
        shutil.rmtree(tmp, ignore_errors=True)
    return final


def cached_recording(scene: str = "structured", frames: int = 300, seed: int = 0, size=(540, 960),
                     progress: bool = True) -> Path:
    """A simulated recording in the cache (:func:`cache_dir`), simulated on first use."""
    H, W = check_args(scene, frames, size)
    return simulated_once(cache_dir() / f"{scene}-{int(frames)}-{int(seed)}-{H}x{W}",
                          scene=scene, frames=frames, seed=seed, size=(H, W), progress=progress)
