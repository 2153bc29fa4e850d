"""Errors that reach the user as one line and exit status 2."""


class InputError(Exception):
    """Bad input: a missing file or key, wrong joint count, NaN, a missing topic...

    The message names the file, field or frame. The CLI prints it as one line
    (``graphtrack: error: <message>``) and exits with status 2; it never shows a
    traceback for this class.
    """


class FrameError(Exception):
    """One bad frame (corrupt image, NaN joints): the frame is skipped and counted.

    ``reason`` is a short, stable key used to count skips in metrics.json
    (e.g. ``"corrupt_image"``, ``"nan_joints"``).
    """

    def __init__(self, frame: int, reason: str, message: str):
        super().__init__(f"frame {frame}: {message}")
        self.frame = frame
        self.reason = reason
