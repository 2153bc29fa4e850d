"""Seeded fuzzing of every parser of user input: robot.json, camera_calibration.yaml,
handeye.yaml, joints.csv, labels.csv and the learned detector's weights metadata.

Each case mutates a valid document (a leaf replaced by a hostile value, a key
dropped or added, a list shortened or lengthened, bytes inserted or cut, lines
swapped) and parses it. The only allowed outcomes are a result that meets the
parser's contract (finite numbers, positive focal lengths, increasing stamps,
...) or :class:`InputError`; any other exception fails the test. A few mutated
recordings also go through ``graphtrack track`` end to end.
"""
from __future__ import annotations

import copy
import csv
import json
import math
import random
from pathlib import Path

import numpy as np
import pytest
import yaml

from graphtrack.errors import InputError

SEED = 21
CASES = 1800   #: mutated documents per parser run (about 4 s on a loaded 2-core machine)
HOSTILE = [None, True, False, "1.57", "", "nan", "\u00ff", float("nan"), float("inf"), float("-inf"),
           1e308, -1e308, 1e-320, 0, -1, 10 ** 30, 2.5, [], {}, [1, 2], [[1, 2, 3]], {"data": [1]},
           [None, None, None], ["a", "b", "c"], [1e30, 0, 0]]


def leaves(doc, path=()):
    """Every (path, value) in a JSON-like document."""
    yield path, doc
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from leaves(v, path + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from leaves(v, path + (i,))


def mutate_doc(doc, rng: random.Random):
    """1-3 structural mutations of a copy of ``doc``."""
    doc = copy.deepcopy(doc)
    for _ in range(rng.randint(1, 3)):
        spots = list(leaves(doc))
        path, value = rng.choice(spots)
        if not path:
            continue
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        key = path[-1]
        op = rng.random()
        if op < 0.6:
            parent[key] = copy.deepcopy(rng.choice(HOSTILE))
        elif op < 0.75:
            del parent[key]
        elif op < 0.85 and isinstance(value, list):
            parent[key] = value + value[:1] if rng.random() < 0.5 else value[:-1]
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            parent[key] = value * rng.choice([-1, 1e6, 1e-6, 0.5, 1e300])
        else:
            parent[key] = copy.deepcopy(rng.choice(HOSTILE))
    return doc


def mutate_bytes(data: bytes, rng: random.Random) -> bytes:
    b = bytearray(data)
    for _ in range(rng.randint(1, 3)):
        op = rng.random()
        at = rng.randrange(len(b) + 1)
        if op < 0.25:
            b[at:at] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
        elif op < 0.45:
            del b[at:at + rng.randint(1, 40)]
        elif op < 0.6:
            b[at:at] = rng.choice([b"nan", b"inf", b"-1e400", b",", b"\n", b"\x00", b"\xff\xfe", b"1e300", b'"'])
        elif op < 0.8:
            lines = bytes(b).split(b"\n")
            i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
            lines[i], lines[j] = lines[j], lines[i]
            b = bytearray(b"\n".join(lines))
        else:
            b = b[:at]
    return bytes(b)


@pytest.fixture(scope="module")
def valid(tmp_path_factory):
    from graphtrack.sim.simulate import simulate

    rec = simulate(tmp_path_factory.mktemp("fuzz") / "rec", frames=8, size=(120, 160), form="folder",
                   progress=False)
    return Path(rec)


# -- the parsers and their contracts ------------------------------------------------------
def check_robot(r):
    nums = [v for j in r.dh for v in (j.alpha, j.A, j.theta, j.D, j.offset)]
    nums += [v for p in r.point_features for v in p.position]
    nums += [v for s in r.shaft_features for v in s.position + s.direction + (s.radius,)]
    assert all(isinstance(v, float) and math.isfinite(v) for v in nums)
    assert all(isinstance(p.link, int) and 0 <= p.link <= r.n_links for p in r.point_features)
    assert all(s.radius > 0 for s in r.shaft_features)
    if r.joint_limits is not None:
        assert np.all(np.isfinite(r.joint_limits))


def check_calibration(c):
    cam = c.left
    assert isinstance(cam.height, int) and isinstance(cam.width, int) and cam.height > 0 and cam.width > 0
    assert np.all(np.isfinite(cam.K)) and cam.K[0, 0] > 0 and cam.K[1, 1] > 0 and cam.K[2, 2] == 1
    assert np.all(np.isfinite(cam.dist))


def check_handeye(E):
    assert E.shape == (4, 4) and np.all(np.isfinite(E)) and np.linalg.norm(E[:3, 3]) <= 5.0
    assert np.allclose(E[:3, :3] @ E[:3, :3].T, np.eye(3), atol=1e-6)


def check_joints(res):
    stamps, joints, jaw = res
    assert np.all(np.isfinite(stamps)) and np.all(np.diff(stamps) > 0)
    assert joints.shape[0] == len(stamps) == len(jaw)


def check_labels(labels, size):
    h, w = size
    for uv in labels.values():
        assert np.all(np.isfinite(uv)) and -10 <= uv[0] <= w + 10 and -10 <= uv[1] <= h + 10


def fuzz_cases(valid: Path, rng: random.Random, tmp: Path):
    """Yield (name, callable) cases, endlessly, cycling over the parsers."""
    from graphtrack.detect.learned import check_meta
    from graphtrack.geometry.camera import load_calibration
    from graphtrack.io.folder import read_joints_csv
    from graphtrack.io.handeye import load_handeye
    from graphtrack.io.labels import read_labels
    from graphtrack.robot.description import load_robot_json

    robot = json.loads((valid / "robot.json").read_text())
    calib = yaml.safe_load((valid / "camera_calibration.yaml").read_text())
    hand = yaml.safe_load((valid / "handeye.yaml").read_text())
    joints = (valid / "joints.csv").read_bytes()
    labels = (valid / "labels.csv").read_bytes()
    meta = {"arch": "linenet-v1", "width": 16, "stem": 8}
    size = (120, 160)

    def write(name, data):
        p = tmp / name
        p.write_bytes(data if isinstance(data, bytes) else data.encode())
        return p

    def dump_yaml(doc, rng):
        text = yaml.safe_dump(doc).encode()
        return mutate_bytes(text, rng) if rng.random() < 0.3 else text

    while True:
        yield "robot.json", lambda: check_robot(load_robot_json(write(
            "robot.json", json.dumps(mutate_doc(robot, rng)) if rng.random() < 0.8
            else mutate_bytes(json.dumps(robot).encode(), rng))))
        yield "camera_calibration.yaml", lambda: check_calibration(load_calibration(write(
            "camera_calibration.yaml", dump_yaml(mutate_doc(calib, rng), rng))))
        yield "handeye.yaml", lambda: check_handeye(load_handeye(write(
            "handeye.yaml", dump_yaml(mutate_doc(hand, rng), rng))))
        yield "joints.csv", lambda: check_joints(read_joints_csv(write("joints.csv", mutate_bytes(joints, rng))))
        yield "labels.csv", lambda: check_labels(read_labels(write("labels.csv", mutate_bytes(labels, rng)), size),
                                                 size)
        yield "weights metadata", lambda: check_meta(mutate_doc(meta, rng), Path("w.pt"))


@pytest.mark.slow
def test_fuzz_parsers(valid, tmp_path):
    rng = random.Random(SEED)
    counts, rejected, crashes = {}, 0, []
    cases = fuzz_cases(valid, rng, tmp_path)
    n = CASES   # a fixed number of cases (seeded): the test's outcome never depends on the machine's speed
    for _ in range(n):
        name, case = next(cases)
        counts[name] = counts.get(name, 0) + 1
        try:
            case()
        except InputError as e:
            rejected += 1
            assert "\n" not in str(e)
        except Exception as e:  # noqa: BLE001 - what the test is for
            crashes.append(f"{name}: {type(e).__name__}: {e}"[:300])
    print(f"fuzz: {n} cases, {rejected} rejected, {len(crashes)} uncaught; {counts}")
    assert not crashes, "\n".join(crashes[:20])
    assert 0 < rejected < n       # the mutations both break and keep documents


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(6))
def test_fuzz_end_to_end(seed, valid, tmp_path, capsys):
    """A mutated recording through ``graphtrack track``: exit 0 with frames tracked, or
    exit 2 with one line; never the internal-error guard, a NaN pose or a NaN in metrics.json."""
    import shutil

    from graphtrack.cli import main

    rng = random.Random(1000 + seed)
    rec = tmp_path / "rec"
    shutil.copytree(valid, rec)
    name = ["robot.json", "camera_calibration.yaml", "handeye.yaml", "joints.csv", "labels.csv", "joints.csv"][seed]
    p = rec / name
    if name.endswith(".json"):
        p.write_text(json.dumps(mutate_doc(json.loads(p.read_text()), rng)))
    elif name.endswith(".yaml"):
        p.write_text(yaml.safe_dump(mutate_doc(yaml.safe_load(p.read_text()), rng)))
    else:
        p.write_bytes(mutate_bytes(p.read_bytes(), rng))
    out = tmp_path / "out"
    capsys.readouterr()
    code = main(["track", str(rec), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert "internal error" not in err and "Traceback" not in err
    assert code in (0, 2), err
    if code == 2:
        assert len([ln for ln in err.splitlines() if ln.startswith("graphtrack: error:")]) == 1
    if (out / "trajectory.csv").is_file():
        rows = list(csv.reader((out / "trajectory.csv").read_text().splitlines()))[1:]
        assert all(math.isfinite(float(v)) for r in rows for v in r[1:9])
        assert code == 2 or len(rows) > 0
    if (out / "metrics.json").is_file():
        json.loads((out / "metrics.json").read_text(), parse_constant=pytest.fail)
