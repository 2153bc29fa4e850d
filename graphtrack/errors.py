"""Errors that reach the user as one line and exit status 2, and the checks that raise them."""

import math
import numbers
import re
from pathlib import Path


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


def one_line(e: BaseException) -> str:
    """An exception's first line (at most 300 characters; its type's name when empty), for
    messages that must stay one line."""
    s = str(e).strip().splitlines()
    return (s[0] if s else type(e).__name__)[:300]


def read_text(path) -> str:
    """The UTF-8 text of a configuration or CSV file; InputError naming the file when it
    is missing, unreadable, or not UTF-8 (with the byte offset of the first bad byte)."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: a folder, not a file")
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    try:
        data = path.read_bytes()
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise InputError(f"{path}: not UTF-8 text (byte {e.start}: {data[e.start:e.start + 1]!r})") from None


#: a number with an exponent that YAML 1.1's float pattern misses (no point, or no sign)
EXPONENT_FLOAT = re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$")


def read_yaml(path):
    """The parsed YAML of a configuration file (InputError naming the file when it is
    not YAML), as OpenCV's FileStorage writes it too: its ``%YAML:1.0`` first line
    (not a YAML directive) is dropped and an ``!!opencv-matrix`` node reads as the
    plain mapping it is (rows, cols, dt, data)."""
    import yaml

    class Loader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            seen = {}
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=True)
                if isinstance(key, (str, int, float, bool)) and key in seen:
                    raise InputError(f"{path}: key {key!r} appears twice (lines {seen[key]} and "
                                     f"{key_node.start_mark.line + 1}): one would silently replace the other")
                seen[key] = key_node.start_mark.line + 1
            return super().construct_mapping(node, deep)

    Loader.add_constructor("tag:yaml.org,2002:opencv-matrix",
                           lambda loader, node: loader.construct_mapping(node, deep=True))
    # YAML 1.1 reads 1e-3, 5e2 and 1.0e6 (an exponent without a point or a sign) as text; they
    # are numbers in YAML 1.2 and to every calibration tool that writes them
    Loader.add_implicit_resolver("tag:yaml.org,2002:float", EXPONENT_FLOAT, list("-+0123456789"))
    text = re.sub(r"^%YAML:1\.0[ \t]*\r?\n", "", read_text(path))
    try:
        return yaml.load(text, Loader=Loader)   # noqa: S506 - a SafeLoader with one more mapping tag
    except yaml.YAMLError as e:
        raise InputError(f"{path}: not valid YAML ({one_line(e)})") from None


def read_json(path):
    """The parsed JSON of a configuration file (robot.json, a dVRK registration): ``//`` and
    ``/* */`` comments outside strings dropped (dVRK files carry them); InputError naming
    the file when it is not JSON or an object holds one key twice (which JSON parsers
    resolve silently, the last one winning)."""
    import json

    path = Path(path)
    text = re.sub(r'("(?:\\.|[^"\\])*")|//[^\n]*|/\*.*?\*/', lambda m: m.group(1) or "", read_text(path),
                  flags=re.S)

    def unique(pairs):
        keys = [k for k, _ in pairs]
        twice = sorted({k for k in keys if keys.count(k) > 1})
        if twice:
            raise InputError(f"{path}: key {twice[0]!r} appears twice in one object: one would silently replace "
                             "the other")
        return dict(pairs)

    try:
        return json.loads(text, object_pairs_hook=unique)
    except json.JSONDecodeError as e:
        raise InputError(f"{path}: not valid JSON (line {e.lineno}: {e.msg})") from None


def is_number(v) -> bool:
    """A finite real number as a parser of JSON/YAML gives it: an int (within float range)
    or a float, never a bool or a string."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    if isinstance(v, int):
        return abs(v) <= 1e300
    return math.isfinite(v)


def is_whole(v) -> bool:
    """An integer (Python's or numpy's), never a bool: what a count or an index may be."""
    return not isinstance(v, bool) and isinstance(v, numbers.Integral)


def number_list(doc: dict, key: str, path, sizes: tuple[int, ...] = (), noun: str = "key",
                missing: str = ""):
    """``doc[key]``, or ``doc[key]["data"]`` (the mapping OpenCV's FileStorage and ROS's
    camera_info YAML write), as a float array: a flat list of finite numbers, of one of
    ``sizes`` values when given. InputError naming ``path`` and the ``noun`` ``key``
    otherwise; ``missing`` is appended to the message when the key is absent."""
    import numpy as np

    if key not in doc:
        raise InputError(f"{path}: missing {noun} '{key}'{missing}")
    v = doc[key]
    if isinstance(v, dict):
        if "data" not in v:
            raise InputError(f"{path}: {noun} '{key}' has no 'data' field")
        v = v["data"]
    if not isinstance(v, list) or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
        raise InputError(f"{path}: {noun} '{key}' must be a flat list of numbers, got {str(v)[:60]}")
    if not all(is_number(x) for x in v):
        raise InputError(f"{path}: {noun} '{key}' holds NaN, infinite or out-of-range values")
    if sizes and len(v) not in sizes:
        raise InputError(f"{path}: {noun} '{key}' has {len(v)} values, expected "
                         f"{' or '.join(map(str, sizes))}")
    return np.asarray(v, dtype=float)


MAX_SEED = 2**32 - 1   #: the largest seed (numpy's and torch's generators both take 0..2**32-1 as given)


def check_seed(seed) -> int:
    """``seed`` as an int in 0..MAX_SEED; InputError naming --seed otherwise."""
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise InputError(f"--seed must be an integer in 0..{MAX_SEED}, got {seed!r}")
    return seed
