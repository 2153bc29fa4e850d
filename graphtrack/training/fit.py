"""The training loop of the learned detector (``graphtrack train``).

Loss: binary cross-entropy with logits on both maps, positives up-weighted
(``pos_weight`` 5 on the line map, 10 on the junction map: edges cover ~1 %
of the pixels), junction loss x 0.5. Targets from
:func:`graphtrack.training.labels.target_maps`.

Augmentation (per sample, on the fly, seeded): horizontal and vertical flips
(image and segments); half the samples turned about the image centre by U(-180, 180) deg,
the border replicated and the segments turned and clipped to the image (the simulator
draws the shaft 20-65 deg from the horizontal, a real view has it at any angle:
docs/decisions/net-orientation.md); brightness gain 0.2-1.5 (half the samples below 0.6:
low light), gamma 0.7-1.8, per-channel gain 0.8-1.2, contrast 0.6-1.2 about
the mean, Gaussian noise sigma 0-0.05, 3x3 box blur 1 in 4.

Optimiser: AdamW (lr 3e-3, weight decay 1e-4), cosine decay to 1e-5, batch 32 (``graphtrack train``'s default).
Fine-tuning (``init``): the same loop started from a weights file's trainable
(unfused) parameters, usually with a lower lr.
Everything is seeded from ``seed`` (torch, the shuffling and augmentation rng);
on the CPU with one thread the same command gives the same weights.
"""
from __future__ import annotations

import time

import cv2
import numpy as np
import torch

from graphtrack.detect.learned import load_weights
from graphtrack.detect.learned_net import ARCH, LineNet
from graphtrack.training.labels import clip_segment, target_maps

TURN_P = 0.5   #: the fraction of training samples turned by a uniform angle


def turn_samples(x, segs, angles, h: int, w: int):
    """Each sample b of x (B, C, h, w) turned about the image centre c = ((w-1)/2, (h-1)/2)
    by angles[b] (rad; positive turns content clockwise on screen, y down), bilinear, the
    border replicated; its segments (B, S, 4) likewise, p' = c + R(a) (p - c), clipped to
    the image [0, w-1] x [0, h-1] (NaN rows where nothing is left). Returns both."""
    B = x.shape[0]
    c, s_ = np.cos(angles), np.sin(angles)
    S = np.diag([(w - 1) / 2.0, (h - 1) / 2.0])
    theta = np.zeros((B, 2, 3))
    for b in range(B):   # the sampling grid maps output to input: p_in = c + R(-a) (p_out - c)
        Rt = np.array([[c[b], s_[b]], [-s_[b], c[b]]])
        theta[b, :, :2] = np.linalg.inv(S) @ Rt @ S
    grid = torch.nn.functional.affine_grid(torch.as_tensor(theta, dtype=x.dtype, device=x.device),
                                           list(x.shape), align_corners=True)
    x = torch.nn.functional.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=True)
    segs = np.array(segs, float)
    ctr = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    lo, hi = np.zeros(2), np.array([w - 1.0, h - 1.0])
    for b in range(B):
        R = np.array([[c[b], -s_[b]], [s_[b], c[b]]])
        for k in range(segs.shape[1]):
            if not np.all(np.isfinite(segs[b, k])):
                continue
            a, e = (R @ (segs[b, k, :2] - ctr) + ctr), (R @ (segs[b, k, 2:] - ctr) + ctr)
            cut = clip_segment(a, e, lo, hi)
            segs[b, k] = np.nan if cut is None else np.concatenate(cut)
    return x, segs


def _augment(x, segs, rng, h: int, w: int):
    """x: (B, 3, h, w) float in [0, 1]; segs (B, S, 4) numpy; returns both augmented."""
    B = x.shape[0]
    segs = segs.copy()
    for b in range(B):
        if rng.uniform() < 0.5:
            x[b] = x[b].flip(-1)
            segs[b, :, 0::2] = (w - 1) - segs[b, :, 0::2]
        if rng.uniform() < 0.5:
            x[b] = x[b].flip(-2)
            segs[b, :, 1::2] = (h - 1) - segs[b, :, 1::2]
    angles = np.where(rng.uniform(size=B) < TURN_P, rng.uniform(-np.pi, np.pi, B), 0.0)
    if np.any(angles):
        x, segs = turn_samples(x, segs, angles, h, w)
    gain = np.where(rng.uniform(size=B) < 0.5, rng.uniform(0.2, 0.6, B), rng.uniform(0.6, 1.5, B))
    gamma = rng.uniform(0.7, 1.8, B)
    chan = rng.uniform(0.8, 1.2, (B, 3))
    contrast = rng.uniform(0.6, 1.2, B)
    sigma = rng.uniform(0.0, 0.05, B)
    blur = rng.uniform(size=B) < 0.25
    t = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    dev = x.device
    t = lambda a: torch.as_tensor(a, dtype=torch.float32, device=dev)  # noqa: E731,F811
    x = x.clamp(0, 1) ** t(gamma).view(B, 1, 1, 1)
    m = x.mean((1, 2, 3), keepdim=True)
    x = (x - m) * t(contrast).view(B, 1, 1, 1) + m
    x = x * t(gain).view(B, 1, 1, 1) * t(chan).view(B, 3, 1, 1)
    if blur.any():
        xb = torch.nn.functional.avg_pool2d(x, 3, 1, 1, count_include_pad=False)
        x = torch.where(t(blur).view(B, 1, 1, 1) > 0, xb, x)
    noise = torch.from_numpy(rng.standard_normal(tuple(x.shape)).astype(np.float32)).to(dev)
    x = x + noise * t(sigma).view(B, 1, 1, 1)
    return x.clamp(0, 1), segs


def jpeg_roundtrip(images: np.ndarray, quality: int = 95) -> np.ndarray:
    """Every training image through JPEG (quality 95), as recorded endoscope video
    usually is; part of the data (also keeps the set small enough to carry)."""
    out = np.empty_like(images)
    for i, im in enumerate(images):
        out[i] = cv2.imdecode(cv2.imencode(".jpg", im, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])[1],
                              cv2.IMREAD_COLOR)
    return out


def initial_net(init=None, width: int = 16, stem: int = 8):
    """A fresh LineNet(width, stem), or the trainable (unfused) net of weights file
    ``init`` (its own width and stem) to fine-tune from; InputError when unusable."""
    if init is None:
        return LineNet(width, stem)
    load_weights(init)  # validates the file (architecture, shapes) with the detector's own checks
    obj = torch.load(str(init), map_location="cpu", weights_only=True)
    net = LineNet(int(obj["width"]), int(obj["stem"]))
    net.load_state_dict(obj["state_dict"], strict=True)
    return net


def train(images: np.ndarray, segments: np.ndarray, epochs: int = 30, seed: int = 0, device: str = "cpu",
          batch: int = 16, lr: float = 3e-3, width: int = 16, stem: int = 8, log=print, init=None):
    """Train a LineNet on (images (N, h, w, 3) uint8 BGR, segments (N, S, 4)), from
    scratch or (``init``: a weights file) fine-tuning those weights;
    returns (net (train mode, on the CPU), stats dict)."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    N, h, w = images.shape[:3]
    net = initial_net(init, width, stem).to(device)
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-4)
    steps = max(1, epochs * int(np.ceil(N / batch)))
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps, eta_min=1e-5)
    pw = torch.tensor([5.0, 10.0], device=device).view(1, 2, 1, 1)
    rgb = torch.from_numpy(np.ascontiguousarray(images[..., ::-1])).permute(0, 3, 1, 2)  # uint8 RGB
    t0 = time.perf_counter()
    losses = []
    for ep in range(epochs):
        net.train()
        order = rng.permutation(N)
        tot, nb = 0.0, 0
        for i in range(0, N, batch):
            idx = order[i:i + batch]
            x = rgb[idx].to(device).float() / 255.0
            x, sg = _augment(x, segments[idx], rng, h, w)
            y = target_maps(torch.from_numpy(sg).to(device), h, w)
            logits = net(x)
            bce = torch.nn.functional.binary_cross_entropy_with_logits(logits, y, pos_weight=pw,
                                                                       reduction="none")
            loss = bce[:, 0].mean() + 0.5 * bce[:, 1].mean()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            tot += float(loss.detach())
            nb += 1
        losses.append(tot / max(nb, 1))
        log(f"epoch {ep + 1}/{epochs}: loss {losses[-1]:.4f} ({time.perf_counter() - t0:.0f} s)")
    net = net.cpu()
    return net, {"epochs": epochs, "final_loss": losses[-1] if losses else float("nan"),
                 "train_seconds": round(time.perf_counter() - t0, 1), "device": device, "batch": batch,
                 "lr": lr, "init": None if init is None else str(init)}


def save(net, path, meta: dict) -> None:
    """Weights file: {"arch", "width", "stem", "state_dict", "meta"} (torch.save;
    loadable with weights_only=True)."""
    sd = {k: v.detach().cpu().clone() for k, v in net.state_dict().items()}
    clean = {k: (v if isinstance(v, (int, float, str, bool)) or v is None else str(v)) for k, v in meta.items()}
    torch.save({"arch": ARCH, "width": net.width, "stem": net.stem_width, "state_dict": sd, "meta": clean},
               str(path))
