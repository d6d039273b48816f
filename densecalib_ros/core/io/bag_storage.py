"""A bag's storage files read record by record, up to where they are damaged.

rosbags opens a bag by its indexes: an mcap cut short has no footer and summary ("File end magic
is invalid"), and a .db3 cut short fails SQLite's page count check, so a bag whose recording was
cut by a full disk or a killed recorder was refused whole. Here:

- mcap_messages reads an mcap from its start, record by record, as a recorder wrote it: every
  record length is checked against the bytes left before it is read, every chunk's size and CRC
  (where the writer stored one), and every chunk's messages against the MessageIndex records
  written after it (channel, log time, offset): the check that notices damage in a bag whose
  chunks carry no CRC (rosbags' writer stores none), where rosbags would drop or reorder such
  a message silently. The data section's CRC is checked where the writer stored one. Damage to
  the image bytes themselves cannot be noticed without a CRC.
- sqlite_messages reads a .db3's messages in the order they were inserted (rowid), with SQLite's
  page count check off, until the first page it cannot read.

Both yield (topic, msgtype, log time ns, raw CDR) and raise StorageDamage at the damage, after
yielding every whole message before it.
"""
from __future__ import annotations

import sqlite3
import struct
import zlib
from pathlib import Path
from typing import Iterator, Optional

MCAP_MAGIC = b"\x89MCAP0\r\n"
SQLITE_MAGIC = b"SQLite format 3\x00"
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, length
_CHUNK_HEAD = struct.Struct("<QQQI")  # start time, end time, uncompressed size, CRC
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel, sequence, log time, publish time
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _MESSAGE_INDEX = 0x03, 0x04, 0x05, 0x06, 0x07
_FOOTER, _DATA_END = 0x02, 0x0F
_KNOWN_OPCODES = range(0x01, 0x11)  # the spec's records; 0x80 and above are user records


class StorageDamage(Exception):
    """Where a storage file stops being readable (the message says what and where)."""


def _string(data: bytes, pos: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(data, pos)
    if pos + 4 + n > len(data):
        raise StorageDamage(f"a string of {n} bytes at byte {pos} runs past its record")
    return data[pos + 4:pos + 4 + n].decode("utf-8", "replace"), pos + 4 + n


def _decompress(data: bytes, compression: str, size: int) -> bytes:
    if compression == "":
        return data
    if compression == "zstd":
        try:
            from compression import zstd
        except ImportError:
            from backports import zstd
        return zstd.decompress(data)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(data)
    raise StorageDamage(f"a chunk is compressed with {compression!r}, which is not read here")


class _Mcap:
    """The state of one sequential read: schemas, channels and the chunk whose messages wait for
    their MessageIndex records."""

    def __init__(self, name: str):
        self.name, self.schemas, self.channels = name, {}, {}
        self.pending: Optional[list] = None  # [(channel id, log time, offset, raw)]
        self.indexed: dict[int, list] = {}  # channel id -> [(log time, offset)] of the pending

    def record(self, opcode: int, body: bytes, pos: int) -> None:
        """Register a schema or channel; anything else is the caller's."""
        try:
            if opcode == _SCHEMA:
                (sid,) = _U16.unpack_from(body, 0)
                name, _ = _string(body, 2)
                self.schemas[sid] = name
            elif opcode == _CHANNEL:
                cid, sid = struct.unpack_from("<HH", body, 0)
                topic, _ = _string(body, 4)
                self.channels[cid] = (topic, self.schemas.get(sid, ""))
        except struct.error:
            raise StorageDamage(f"{self.name}: a record at byte {pos} is cut short") from None

    def chunk(self, body: bytes, pos: int, cut: bool = False) -> None:
        """Read a chunk's records into self.pending (its size and CRC checked). cut: the file
        ends inside this chunk: the whole records of an uncompressed chunk are read (as `mcap
        recover` does), then StorageDamage."""
        try:
            start, end, size, crc = _CHUNK_HEAD.unpack_from(body, 0)
            compression, at = _string(body, _CHUNK_HEAD.size)
            (stored,) = _U64.unpack_from(body, at)
        except struct.error:
            raise StorageDamage(f"{self.name}: the chunk at byte {pos} is cut short") from None
        if cut and compression == "":
            self._records(body[at + 8:at + 8 + stored], pos, (start, end), cut=True)
            return
        if at + 8 + stored != len(body):
            raise StorageDamage(f"{self.name}: the chunk at byte {pos} holds {len(body) - at - 8} "
                                f"bytes of records, its header says {stored}")
        try:
            records = _decompress(body[at + 8:], compression, size)
        except StorageDamage:
            raise
        except Exception as exc:  # zstd and lz4 raise types of their own
            raise StorageDamage(f"{self.name}: the chunk at byte {pos} does not decompress "
                                f"({exc})") from None
        if len(records) != size or (crc and zlib.crc32(records) != crc):
            raise StorageDamage(f"{self.name}: the chunk at byte {pos} fails its "
                                f"{'size' if len(records) != size else 'CRC'} check")
        self._records(records, pos, (start, end))

    def _records(self, records: bytes, pos: int, span: tuple, cut: bool = False) -> None:
        """The chunk's schemas and channels registered, its messages into self.pending; a
        record that does not fit is damage, except the last of a cut chunk (left out)."""
        self.pending, self.indexed, offset = [], {}, 0
        while offset < len(records):
            opcode, length = _RECORD_HEAD.unpack_from(records, offset) \
                if offset + 9 <= len(records) else (None, 0)
            body_at = offset + 9
            if cut and (opcode is None or body_at + length > len(records)):
                return
            if opcode not in (_SCHEMA, _CHANNEL, _MESSAGE) or body_at + length > len(records):
                raise StorageDamage(f"{self.name}: the chunk at byte {pos} holds a broken record "
                                    f"at offset {offset}")
            inner = records[body_at:body_at + length]
            if opcode == _MESSAGE:
                self.pending.append(self._message(inner, pos, offset, span))
            else:
                self.record(opcode, inner, pos)
            offset = body_at + length

    def _message(self, body: bytes, pos: int, offset: int, span=None) -> tuple:
        if len(body) < _MESSAGE_HEAD.size:
            raise StorageDamage(f"{self.name}: a message at byte {pos} is cut short")
        cid, _, log_time, _ = _MESSAGE_HEAD.unpack_from(body, 0)
        if cid not in self.channels:
            raise StorageDamage(f"{self.name}: a message at byte {pos} names channel {cid}, which "
                                "the bag never defined")
        if span is not None and not span[0] <= log_time <= span[1]:
            raise StorageDamage(f"{self.name}: a message in the chunk at byte {pos} has a log "
                                "time outside its chunk's")
        return cid, log_time, offset, body[_MESSAGE_HEAD.size:]

    def index(self, body: bytes, pos: int) -> None:
        if self.pending is None:
            raise StorageDamage(f"{self.name}: a message index at byte {pos} follows no chunk")
        try:
            (cid,) = _U16.unpack_from(body, 0)
            (n,) = _U32.unpack_from(body, 2)
        except struct.error:
            raise StorageDamage(f"{self.name}: the message index at byte {pos} is cut "
                                "short") from None
        if 6 + n != len(body) or n % 16:
            raise StorageDamage(f"{self.name}: the message index at byte {pos} is broken")
        self.indexed[cid] = [struct.unpack_from("<QQ", body, 6 + k) for k in range(0, n, 16)]

    def flush(self) -> list:
        """The pending chunk's messages in log time order, checked against their index."""
        pending, self.pending = self.pending or [], None
        indexed, self.indexed = self.indexed, {}
        for cid, entries in indexed.items():
            if sorted(entries) != sorted((t, off) for c, t, off, _ in pending if c == cid):
                raise StorageDamage(f"{self.name}: a chunk's messages of "
                                    f"{self.channels.get(cid, (cid,))[0]} differ from its index "
                                    "(a damaged message header)")
        return sorted(pending, key=lambda m: m[1])


def mcap_messages(path: Path) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, msgtype, log time ns, raw) of every message of an mcap file in file order (each
    chunk's in log time order); StorageDamage where it stops being whole (module docstring)."""
    size = path.stat().st_size
    state = _Mcap(path.name)
    with open(path, "rb") as f:
        magic = f.read(8)
        if magic != MCAP_MAGIC:
            raise StorageDamage(f"{path.name} does not start as an mcap file")
        crc, pos = zlib.crc32(magic), 8
        while True:
            head = f.read(9)
            if len(head) < 9 or _RECORD_HEAD.unpack(head)[1] > size - pos - 9:
                yield from _named(state, state.flush())
                if len(head) == 9 and head[0] == _CHUNK:  # its whole messages, where readable
                    state.chunk(f.read(), pos, cut=True)
                    yield from _named(state, state.flush())
                raise StorageDamage(f"{path.name} is cut short at byte {size} (a record at byte "
                                    f"{pos} is not whole; no footer)")
            opcode, length = _RECORD_HEAD.unpack(head)
            body = f.read(length)
            if opcode in (_DATA_END, _FOOTER):
                yield from _named(state, state.flush())
                if opcode == _DATA_END and len(body) >= 4 and _U32.unpack_from(body)[0] not in (
                        0, crc):
                    raise StorageDamage(f"{path.name} fails its data section CRC")
                return
            if opcode == _MESSAGE_INDEX:
                state.index(body, pos)
            else:
                yield from _named(state, state.flush())
                if opcode == _CHUNK:
                    try:
                        state.chunk(body, pos)
                    except StorageDamage:  # a chunk without CRC: its records before the damage
                        yield from _named(state, state.flush())
                        raise
                elif opcode == _MESSAGE:
                    yield from _named(state, [state._message(body, pos, 0)])
                elif opcode in (_SCHEMA, _CHANNEL):
                    state.record(opcode, body, pos)
                elif opcode not in _KNOWN_OPCODES and opcode < 0x80:
                    raise StorageDamage(f"{path.name} holds a record of unknown kind "
                                        f"0x{opcode:02x} at byte {pos}")
            crc = zlib.crc32(body, zlib.crc32(head, crc))
            pos += 9 + length


def _named(state: _Mcap, messages: list) -> Iterator[tuple[str, str, int, bytes]]:
    for cid, log_time, _, raw in messages:
        topic, msgtype = state.channels[cid]
        yield topic, msgtype, log_time, raw


def sqlite_messages(path: Path) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, msgtype, log time ns, raw) of a rosbag2 .db3's messages in the order they were
    written (rowid), up to the first page SQLite cannot read (StorageDamage)."""
    try:
        db = sqlite3.connect(f"file:{path}?mode=ro&immutable=1", uri=True)
    except sqlite3.Error as exc:
        raise StorageDamage(f"{path.name} cannot be opened ({exc})") from None
    try:
        db.execute("PRAGMA writable_schema=ON")  # past the header's page count (a cut file)
        read = 0
        try:
            topics = {tid: (name, msgtype) for tid, name, msgtype in
                      db.execute("SELECT id, name, type FROM topics")}
            for tid, stamp, data in db.execute("SELECT topic_id, timestamp, data FROM messages "
                                               "ORDER BY rowid"):
                if tid in topics:
                    yield *topics[tid], int(stamp), data
                read += 1
        except sqlite3.Error as exc:
            raise StorageDamage(f"{path.name} stops being readable after {read} messages "
                                f"({exc})") from None
    finally:
        db.close()


def storage_files(bag_path: str | Path) -> Optional[list[Path]]:
    """The storage files of a bag (a .mcap or .db3 file, or a rosbag2 folder: the files its
    metadata.yaml lists, else its .mcap/.db3 files), or None where they are not plain mcap or
    sqlite3 files read here (compressed as whole files, another storage)."""
    path = Path(bag_path)
    if path.is_file():
        files = [path]
    else:
        files = _listed_files(path)
        if files is None:
            files = sorted(p for p in path.glob("*") if p.suffix in (".mcap", ".db3"))
    if not files or any(p.suffix not in (".mcap", ".db3") or not p.is_file() for p in files):
        return None
    return files


def _listed_files(folder: Path) -> Optional[list[Path]]:
    import yaml

    try:
        info = yaml.safe_load((folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        if str(info.get("compression_mode") or "").lower() == "file":
            return []
        return [folder / p for p in info["relative_file_paths"]]
    except (OSError, ValueError, KeyError, TypeError, yaml.YAMLError):
        return None


def storage_messages(path: Path) -> Iterator[tuple[str, str, int, bytes]]:
    """mcap_messages or sqlite_messages by the file's first bytes."""
    with open(path, "rb") as f:
        head = f.read(16)
    if head.startswith(MCAP_MAGIC):
        return mcap_messages(path)
    if head == SQLITE_MAGIC:
        return sqlite_messages(path)
    raise StorageDamage(f"{path.name} is neither an mcap nor a sqlite3 file (its first bytes)")
