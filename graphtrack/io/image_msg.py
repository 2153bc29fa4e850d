"""sensor_msgs images -> BGR arrays, and a check for damaged raw image data.

Raw images (``sensor_msgs/msg/Image``: rgb8, bgr8, mono8 / 8UC1, 8UC3, rgba8,
bgra8, and a camera's colour-filter mosaic bayer_rggb8 / bggr8 / gbrg8 / grbg8,
demosaiced by OpenCV; rows of ``step`` bytes) and compressed ones (``CompressedImage``: any
format cv2.imdecode reads) decode to H x W x 3 uint8 BGR. Raw messages carry no
checksum, so :func:`noise_span` looks for random bytes in a decoded raw image.
"""
from __future__ import annotations

import cv2
import numpy as np

from graphtrack.errors import InputError
from graphtrack.io.decode import decode_bytes

IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_TYPE = "sensor_msgs/msg/CompressedImage"
#: ROS Bayer encodings (the mosaic's top-left 2x2, row by row) -> OpenCV's demosaicing code
BAYER = {"bayer_rggb8": cv2.COLOR_BayerRGGB2BGR, "bayer_bggr8": cv2.COLOR_BayerBGGR2BGR,
         "bayer_gbrg8": cv2.COLOR_BayerGBRG2BGR, "bayer_grbg8": cv2.COLOR_BayerGRBG2BGR}


def decode_image(msg, msgtype: str, where: str) -> np.ndarray:
    """sensor_msgs Image / CompressedImage -> H x W x 3 uint8 BGR (a fresh, writable array).

    Raises ValueError for corrupt data (the frame is skipped) and InputError for
    an encoding graphtrack does not read (every frame would fail alike).
    """
    if msgtype == COMPRESSED_TYPE:
        img, why = decode_bytes(msg.data)
        if img is None:
            raise ValueError(f"compressed image ({msg.format!r}) does not decode" + (f" ({why})" if why else ""))
        return img
    enc = msg.encoding.lower()
    channels = {"rgb8": 3, "bgr8": 3, "mono8": 1, "8uc1": 1, "8uc3": 3, "rgba8": 4, "bgra8": 4,
                **dict.fromkeys(BAYER, 1)}
    if enc not in channels:
        raise InputError(f"{where}: image encoding {msg.encoding!r} is not supported "
                         f"(rgb8, bgr8, mono8, rgba8, bgra8, {', '.join(BAYER)})")
    h, w, c, step = int(msg.height), int(msg.width), channels[enc], int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8).ravel()
    if h <= 0 or w <= 0 or step < w * c or data.size < step * (h - 1) + w * c:
        raise ValueError(f"raw image data has {data.size} bytes, too few for {w}x{h} {enc} (step {step})")
    if data.size < step * h:
        data = np.concatenate([data, np.zeros(step * h - data.size, np.uint8)])
    img = data[: step * h].reshape(h, step)[:, : w * c].reshape(h, w, c)
    conv = {"rgb8": cv2.COLOR_RGB2BGR, "rgba8": cv2.COLOR_RGBA2BGR, "bgra8": cv2.COLOR_BGRA2BGR,
            "mono8": cv2.COLOR_GRAY2BGR, "8uc1": cv2.COLOR_GRAY2BGR, **BAYER}.get(enc)
    return cv2.cvtColor(img, conv) if conv is not None else img.copy()


#: noise_span's window (px) and threshold (mean |difference| of neighbouring green values)
NOISE_WINDOW_PX, NOISE_LEVEL = 512, 40.0


def noise_span(image: np.ndarray) -> str | None:
    """Where a raw image holds random bytes (damaged bag data), or None.

    Raw messages carry no checksum, so overwritten bytes decode as an image. In
    row-major pixel order, every window of ``NOISE_WINDOW_PX`` pixels gets the
    mean |g[i+1] - g[i]| of its green values at every 4th i: uniform random
    bytes give ~85, camera images (smooth at the pixel scale) well under 20; a
    window above ``NOISE_LEVEL`` in an image whose median window is under half
    of it is damage (an image noisy all over is taken as a picture). Any run of
    >= 2 windows of bytes (3 KB of rgb8) covers one whole window.
    """
    c = image.shape[2] if image.ndim == 3 else 1
    flat = np.ascontiguousarray(image).reshape(-1)   # a view of a decoded image: no copy
    n = (flat.size // c // NOISE_WINDOW_PX) * NOISE_WINDOW_PX
    if n == 0:
        return None
    # green of pixels 4k and 4k+1 read in place (bytes 4kc + g and 4kc + c + g), not
    # through a copy of the whole green plane (half the time: 0.3 -> 0.18 ms per 540x960 image)
    quads = flat[: n * c].reshape(-1, NOISE_WINDOW_PX // 4, 4 * c)
    g0 = 1 if image.ndim == 3 else 0
    d = np.abs(quads[..., g0].astype(np.int16) - quads[..., c + g0]).mean(axis=1)
    bad = np.flatnonzero(d > NOISE_LEVEL)
    if bad.size == 0 or np.median(d) > NOISE_LEVEL / 2:   # noisy all over: a picture of noise
        return None
    w = image.shape[1]
    r0, r1 = bad[0] * NOISE_WINDOW_PX // w, ((bad[-1] + 1) * NOISE_WINDOW_PX - 1) // w
    return f"image rows {r0}..{r1} hold random-looking bytes (damaged image data)"
