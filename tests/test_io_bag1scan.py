"""Index-free scan of ROS 1 bags (graphtrack.io.bag1scan) against rosbags' indexed reader."""
from types import SimpleNamespace

import numpy as np
import pytest

from graphtrack.io.bag1scan import Bag1Scan
from graphtrack.io.bag_write import write_bag

N = 12


def frames(n=N):
    rng = np.random.default_rng(0)
    for k in range(n):
        yield SimpleNamespace(stamp=10.0 + k / 30, image=rng.integers(0, 256, (24, 32, 3), dtype=np.uint8),
                              joints=np.arange(6) * 0.1 + k, jaw=0.2 + 0.01 * k)


def indexed(path):
    """(topic, ns, raw) in file order by rosbags' Reader (the index): the oracle."""
    from rosbags.rosbag1 import Reader

    with Reader(path) as r:
        return [(c.topic, t, bytes(raw)) for c, t, raw in r.messages()]


def scanned(path):
    scan = Bag1Scan(path)
    out = [(c.topic, t, bytes(raw)) for c, t, raw in scan.messages()]
    return scan, out


@pytest.fixture(scope="module", params=[None, "bz2"])
def bag(tmp_path_factory, request):
    path = tmp_path_factory.mktemp("bag") / "rec.bag"
    assert write_bag(path, frames(), chunk_compression=request.param) == N
    return path


def test_intact_bag_matches_the_index(bag):
    scan, got = scanned(bag)
    want = indexed(bag)
    assert not scan.truncated and scan.stop_reason == ""
    assert sorted(got) == sorted(want) and len(got) == 3 * N       # image, joints, jaw per frame
    topics = {c.topic: c.msgtype for c in scan.connections.values()}
    assert len(topics) == 3 and all(t.count("/msg/") == 1 for t in topics.values())
    stamps = sorted({t for _, t, _ in got})
    np.testing.assert_array_equal(stamps, [round((10.0 + k / 30) * 1e9) for k in range(N)])


@pytest.mark.parametrize("fraction", [0.3, 0.6, 0.95])
def test_truncated_bag_yields_a_prefix(bag, tmp_path, fraction):
    """Cut anywhere: the complete messages before the cut, in file order, and truncated."""
    data = bag.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: int(fraction * len(data))])
    scan, got = scanned(cut)
    _, full = scanned(bag)
    assert scan.truncated and scan.stop_reason
    assert got == full[: len(got)]
    if b"compression=none" in data:   # an uncompressed partial chunk salvages its complete records
        assert len(got) >= int(0.8 * fraction * len(full)) - 3   # (a bz2 block decompresses only whole)


def test_corrupt_header_length_stops_the_scan(bag, tmp_path):
    """A record header length of 2^32 - 1 after the bag header record: malformed, nothing after."""
    data = bytearray(bag.read_bytes())
    start = len(b"#ROSBAG V2.0\n")
    hlen = int.from_bytes(data[start:start + 4], "little")
    dlen_at = start + 4 + hlen
    dlen = int.from_bytes(data[dlen_at:dlen_at + 4], "little")
    nxt = dlen_at + 4 + dlen                     # the first record after the bag header
    data[nxt:nxt + 4] = b"\xff\xff\xff\xff"
    bad = tmp_path / "bad.bag"
    bad.write_bytes(bytes(data))
    scan, got = scanned(bad)
    assert got == [] and scan.truncated and "implausible" in scan.stop_reason


def test_not_a_bag(tmp_path):
    p = tmp_path / "x.bag"
    p.write_bytes(b"#ROSBAG V1.2\n" + bytes(100))
    with pytest.raises(ValueError, match="not a ROS 1 bag"):
        list(Bag1Scan(p).messages())
    p.write_bytes(b"")
    with pytest.raises(ValueError):
        list(Bag1Scan(p).messages())


def test_empty_bag_after_the_magic_is_clean(tmp_path):
    p = tmp_path / "e.bag"
    p.write_bytes(b"#ROSBAG V2.0\n")
    scan, got = scanned(p)
    assert got == [] and not scan.truncated
