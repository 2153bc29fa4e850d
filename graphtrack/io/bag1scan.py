"""Linear scan of a ROS 1 bag (format v2.0) WITHOUT its index: salvage of truncated bags.

rosbags (like ``rosbag``) reads a bag through the index written at its end, so
it refuses a bag whose recording was killed (``index_pos = 0``, "not indexed";
e.g. a ``.bag.active`` file) or that was cut short by a full disk or a partial
copy (index missing or pointing past the end). Every message record before the
damage is still intact, though. This module walks the records from the start,
like ``rosbag reindex`` does, and yields the connections and the complete
messages, stopping quietly at the first truncated or malformed record.

Record layout (http://wiki.ros.org/Bags/Format/2.0)::

    <header_len u32><header: (<field_len u32><name>=<value>)*><data_len u32><data>

op codes: 0x02 message data (conn u32, time u32 sec + u32 nsec), 0x03 bag header,
0x04 index data, 0x05 chunk (compression none/bz2/lz4; data holds connection and
message records), 0x06 chunk info, 0x07 connection (conn, topic; data holds
topic/type/md5sum/message_definition fields).

Memory: one chunk at a time (rosbag's default chunk is 768 KiB; a chunk holds
at least one message).
"""
from __future__ import annotations

import bz2
import io
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Iterator

import lz4.frame  # installed with rosbags, which reads lz4 chunks the same way

_MAX_HEADER = 1 << 20          # a header longer than this is corruption, not data
OP_MSGDATA, OP_BAGHEADER, OP_IDXDATA, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7


@dataclass
class ScanConnection:
    """A connection record: id, topic and message type (``pkg/msg/Name``)."""

    id: int
    topic: str
    msgtype: str


def parse_fields(buf: bytes) -> dict[str, bytes]:
    """``(<len u32><name>=<value>)*`` -> {name: value bytes}; ValueError when malformed."""
    out: dict[str, bytes] = {}
    i = 0
    while i < len(buf):
        if i + 4 > len(buf):
            raise ValueError("truncated header field")
        (n,) = struct.unpack_from("<I", buf, i)
        field = buf[i + 4:i + 4 + n]
        if len(field) != n or b"=" not in field:
            raise ValueError("malformed header field")
        name, value = field.split(b"=", 1)
        out[name.decode("ascii", "replace")] = value
        i += 4 + n
    return out


def _normalize(msgtype: str) -> str:
    parts = msgtype.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else msgtype


class Bag1Scan:
    """Iterate a ROS 1 bag's records in file order without its index.

    After (or during) iteration: ``truncated`` is True when the scan stopped at
    a damaged/partial record rather than at a clean end of file, and
    ``stop_reason`` says why.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.connections: dict[int, ScanConnection] = {}
        self.truncated = False
        self.stop_reason = ""

    # -- low level ------------------------------------------------------------------
    @staticmethod
    def _read_record(f: BinaryIO, limit: int | None = None) -> tuple[dict, bytes, int] | None:
        """Read one record -> (fields, data, declared data length), or None at a clean end.

        ``data`` may be shorter than declared when the file ends inside it
        (only returned for chunks, which the caller can partly salvage);
        raises ValueError on a malformed or partial header.
        """
        raw = f.read(4)
        if not raw:
            return None
        if len(raw) < 4:
            raise ValueError("file ends inside a record length")
        (hlen,) = struct.unpack("<I", raw)
        if hlen > _MAX_HEADER:
            raise ValueError(f"implausible record header length {hlen}")
        head = f.read(hlen)
        if len(head) < hlen:
            raise ValueError("file ends inside a record header")
        fields = parse_fields(head)
        raw = f.read(4)
        if len(raw) < 4:
            raise ValueError("file ends inside a record length")
        (dlen,) = struct.unpack("<I", raw)
        if limit is not None and dlen > limit:
            raise ValueError(f"record data length {dlen} beyond the end")
        data = f.read(dlen)
        return fields, data, dlen

    def _records(self, f: BinaryIO, inner: bool) -> Iterator[tuple[dict, bytes]]:
        while True:
            try:
                rec = self._read_record(f)
            except ValueError as e:
                self.truncated, self.stop_reason = True, str(e)
                return
            if rec is None:
                return
            fields, data, dlen = rec
            op = fields.get("op", b"\0")[0]
            if len(data) < dlen:
                if op == OP_CHUNK and not inner:
                    yield fields, data  # partial chunk: the caller salvages what decompresses
                self.truncated, self.stop_reason = True, "file ends inside a record"
                return
            yield fields, data

    def _chunk_payload(self, fields: dict, data: bytes) -> bytes:
        comp = fields.get("compression", b"none").decode()
        if comp == "none":
            return data
        try:
            if comp == "bz2":
                return bz2.BZ2Decompressor().decompress(data)
            if comp == "lz4":
                return lz4.frame.LZ4FrameDecompressor().decompress(data)
        except Exception as e:  # noqa: BLE001 - corrupt compressed data ends the scan
            self.truncated, self.stop_reason = True, f"chunk does not decompress ({e})"
            return b""
        self.truncated, self.stop_reason = True, f"unsupported chunk compression {comp!r}"
        return b""

    def _connection(self, fields: dict, data: bytes) -> None:
        (cid,) = struct.unpack("<I", fields["conn"][:4])
        info = parse_fields(data)
        topic = (info.get("topic") or fields.get("topic", b"")).decode()
        msgtype = _normalize(info.get("type", b"").decode())
        self.connections[cid] = ScanConnection(cid, topic, msgtype)

    # -- public ---------------------------------------------------------------------
    def messages(self) -> Iterator[tuple[ScanConnection, int, bytes]]:
        """Yield (connection, bag time ns, raw ROS 1 message bytes) in file order.

        Raises ValueError when the file is not a ROS 1 bag v2.0 at all.
        """
        self.truncated, self.stop_reason = False, ""
        with self.path.open("rb") as f:
            if f.readline() != b"#ROSBAG V2.0\n":
                raise ValueError("not a ROS 1 bag (v2.0 magic missing)")
            yield from self._walk(self._records(f, inner=False))

    def _walk(self, records: Iterator[tuple[dict, bytes]]) -> Iterator[tuple[ScanConnection, int, bytes]]:
        for fields, data in records:
            try:
                op = fields.get("op", b"\0")[0]
                if op == OP_CONNECTION:
                    self._connection(fields, data)
                elif op == OP_MSGDATA:
                    (cid,) = struct.unpack("<I", fields["conn"][:4])
                    sec, nsec = struct.unpack("<II", fields["time"][:8])
                    conn = self.connections.get(cid)
                    if conn is not None:
                        yield conn, sec * 1_000_000_000 + nsec, data
                elif op == OP_CHUNK:
                    payload = self._chunk_payload(fields, data)
                    was_truncated, reason = self.truncated, self.stop_reason
                    yield from self._walk(self._records(io.BytesIO(payload), inner=True))
                    # a partial chunk ends the file; a clean chunk must parse completely
                    self.truncated = self.truncated or was_truncated
                    self.stop_reason = reason or self.stop_reason
                    if self.truncated:   # a chunk that did not decompress or parse: nothing after it
                        return           # may be read, or later messages would take its frames' numbers
            except (KeyError, struct.error, ValueError, UnicodeDecodeError) as e:
                self.truncated, self.stop_reason = True, f"malformed record ({e})"
                return
