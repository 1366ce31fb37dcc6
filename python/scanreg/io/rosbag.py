"""ROS bags: ``sensor_msgs/LaserScan`` and ``sensor_msgs/PointCloud2`` from ROS 1 and ROS 2.

* **ROS 1** (``.bag``, format 2.0): read by our own record walker, which follows the chunk
  records in file order and never trusts the index-data records (op ``0x04``). The walker
  exists because real bags carry non-standard index records (the CCNY ``laser_scan_matcher``
  demo bag declares a data length of 20 bytes per index entry but writes the spec's 12)
  that make stock readers fail. The
  record layout is the one documented for the ROS bag format 2.0 on the ROS wiki; chunks
  may be uncompressed, ``bz2`` or ``lz4``.
* **ROS 2** (a bag folder with ``metadata.yaml``, or a single ``.db3`` / ``.mcap`` file):
  read with ``rosbags.rosbag2.Reader`` (sqlite3 and mcap storage).

Message bytes are deserialised by the ``rosbags`` package in both cases (an optional
dependency: ``pip install scanreg[ros]``), imported only when a bag is read.

>>> scans = read_bag_scans("demo.bag")                 # list of RosLaserScan
>>> clouds = read_bag_clouds("drive_mcap/", topic="/velodyne_points")
>>> list_topics("demo.bag")
(BagTopic(name='/scan', msgtype='sensor_msgs/msg/LaserScan', message_count=360),)

Every problem with the file (truncated, corrupt record, inconsistent message) raises
:class:`~scanreg.io.FileFormatError` naming the file.
"""

from __future__ import annotations

import bz2
import errno
import functools
import io
import os
import stat
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import NDArray

from .._validate import FloatArray
from ._common import FileFormatError, PathLike, PointCloud, _readonly, cloud_from_columns
from .carmen import LaserScan

LASER_SCAN = "sensor_msgs/msg/LaserScan"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"

_ROS1_MAGIC = b"#ROSBAG V2.0\n"
_OP_MESSAGE, _OP_BAG_HEADER, _OP_INDEX, _OP_CHUNK, _OP_CHUNK_INFO, _OP_CONNECTION = (
    0x02,
    0x03,
    0x04,
    0x05,
    0x06,
    0x07,
)
#: Largest record header we accept (real headers are a few hundred bytes; the connection
#: record's data holds the message definition, but its *header* is small).
_MAX_HEADER = 1 << 20

#: ``sensor_msgs/PointField`` datatypes → numpy type codes (byte order added per message).
POINTFIELD_DTYPES: dict[int, str] = {
    1: "i1",  # INT8
    2: "u1",  # UINT8
    3: "i2",  # INT16
    4: "u2",  # UINT16
    5: "i4",  # INT32
    6: "u4",  # UINT32
    7: "f4",  # FLOAT32
    8: "f8",  # FLOAT64
}


def _rosbags() -> Any:
    try:
        import rosbags.typesys
    except ImportError:  # pragma: no cover - exercised only without the extra
        raise ImportError(
            "reading ROS bags needs the 'rosbags' package: pip install 'scanreg[ros]' "
            "(or pip install rosbags)"
        ) from None
    return rosbags


# --------------------------------------------------------------------------- results


@dataclass(frozen=True)
class BagTopic:
    """One topic of a bag: its name, message type (ROS 2 spelling) and message count."""

    name: str
    msgtype: str
    message_count: int


@dataclass(frozen=True)
class RosLaserScan(LaserScan):
    """A ``sensor_msgs/LaserScan`` message: a :class:`~scanreg.io.LaserScan` plus ROS fields.

    As a ``LaserScan``: ``kind`` is ``"sensor_msgs/LaserScan"``, ``ranges`` as logged (metres,
    float32 widened), ``angles = angle_min + k·angle_increment``, ``max_range`` the message's
    ``range_max``, ``timestamp`` the header stamp and ``logger_timestamp`` the bag's receive
    time (both seconds), ``laser_pose``/``odometry_pose`` None.

    Attributes
    ----------
    topic, frame_id : str
    range_min : float
        Readings at or below it are invalid: :meth:`valid` and :meth:`to_points` never keep
        them (ROS semantics), whatever ``min_range`` they are given.
    intensities : (n,) float64 or None
        None when the message has none.
    time_increment, scan_time : float
        Seconds between beams and between scans, as in the message.
    angle_increment : float
        Radians between beams.
    """

    topic: str = ""
    frame_id: str = ""
    range_min: float = 0.0
    intensities: FloatArray | None = None
    time_increment: float = 0.0
    scan_time: float = 0.0
    angle_increment: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (np.isfinite(self.range_min) and 0 <= self.range_min < self.max_range):
            raise ValueError(
                f"range_min: must be finite, >= 0 and < max_range, got {self.range_min}"
            )
        if self.intensities is not None:
            inten = np.array(self.intensities, dtype=np.float64)
            if inten.shape != self.ranges.shape:
                raise ValueError(
                    f"intensities: expected shape {self.ranges.shape}, got {inten.shape}"
                )
            object.__setattr__(self, "intensities", _readonly(inten))

    def valid(self, min_range: float = 0.0, max_range: float | None = None) -> NDArray[np.bool_]:
        """As :meth:`LaserScan.valid`, and never below the message's ``range_min``."""
        return super().valid(max(float(min_range), self.range_min), max_range)

    @property
    def beam_times(self) -> FloatArray:
        """Time of each beam relative to :attr:`timestamp`: ``k · time_increment`` (seconds)."""
        return np.arange(len(self), dtype=np.float64) * self.time_increment


@dataclass(frozen=True)
class BagCloud:
    """A ``sensor_msgs/PointCloud2`` message.

    Attributes
    ----------
    cloud : PointCloud
        ``width·height`` points in row-major order (organised clouds keep their NaN points;
        use ``cloud.finite()``), with intensity, ring and per-point time as stored.
    timestamp : float
        Header stamp, seconds.
    bag_time : float
        The bag's receive time, seconds.
    topic, frame_id : str
    height, width : int
        ``height > 1`` for an organised cloud.
    is_dense : bool
        As declared by the message (True: no invalid points).
    """

    cloud: PointCloud
    timestamp: float
    bag_time: float
    topic: str
    frame_id: str
    height: int
    width: int
    is_dense: bool


# --------------------------------------------------------------------------- PointCloud2


def decode_pointcloud2(
    fields: Any,
    data: Any,
    *,
    height: int,
    width: int,
    point_step: int,
    row_step: int,
    is_bigendian: bool,
) -> PointCloud:
    """Decode the ``data`` blob of a ``sensor_msgs/PointCloud2`` into a :class:`PointCloud`.

    Parameters
    ----------
    fields : sequence of objects with ``name``, ``offset``, ``datatype``, ``count``
        The message's ``PointField`` list (``x``, ``y``, ``z`` required).
    data : bytes-like or uint8 array
        ``height`` rows of ``row_step`` bytes, each holding ``width`` points of ``point_step``
        bytes (row padding is allowed and skipped).

    Vectorised: one structured-dtype view per message, no per-point Python loop. Fields with
    ``count > 1`` become ``(N, count)`` columns in ``cloud.fields``.
    """
    for name, value in (("height", height), ("width", width)):
        if value < 0:
            raise ValueError(f"{name}: must be >= 0, got {value}")
    if point_step <= 0:
        raise ValueError(f"point_step: must be > 0, got {point_step}")
    if row_step < width * point_step:
        raise ValueError(
            f"row_step: {row_step} bytes is less than width·point_step = {width * point_step}"
        )
    blob = np.frombuffer(memoryview(data), dtype=np.uint8)
    needed = height * row_step
    used = width * point_step  # the bytes of a row that hold points
    if height > 0 and blob.size < (height - 1) * row_step + used:
        raise ValueError(
            f"data: {blob.size} bytes, expected height·row_step = {needed} "
            f"({height} rows of {row_step} bytes)"
        )
    order = ">" if is_bigendian else "<"
    names: list[str] = []
    formats: list[Any] = []
    offsets: list[int] = []
    for f in fields:
        name, offset, datatype, count = str(f.name), int(f.offset), int(f.datatype), int(f.count)
        if datatype not in POINTFIELD_DTYPES:
            raise ValueError(f"fields: {name!r} has unknown datatype {datatype}")
        code = order + POINTFIELD_DTYPES[datatype]
        size = np.dtype(code).itemsize * max(count, 1)
        if offset < 0 or offset + size > point_step:
            raise ValueError(
                f"fields: {name!r} (offset {offset}, {size} bytes) lies outside "
                f"point_step = {point_step}"
            )
        if name in names:
            raise ValueError(f"fields: {name!r} appears twice")
        if count == 0:
            continue
        names.append(name)
        formats.append(code if count == 1 else (code, (count,)))
        offsets.append(offset)
    dtype = np.dtype(
        {"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step}
    )
    n = height * width
    if n == 0:
        records = np.zeros(0, dtype=dtype)
    else:
        # The rows' point bytes, padding skipped, read in place: the last row's trailing
        # padding may be missing. (Padding the blob out to height·row_step instead let a
        # 6 kB bag with a 1 GiB row_step allocate 1 GiB; found by fuzz/, ros1 and ros2_mcap.)
        # Bounds checked above: the last row ends at (height-1)·row_step + used <= blob.size.
        rows = np.lib.stride_tricks.as_strided(
            blob, shape=(height, used), strides=(row_step, 1), writeable=False
        )
        records = np.ascontiguousarray(rows).view(dtype).reshape(n)
    # float32 → float64 raises an "invalid" FP flag on signalling NaNs: they are plain NaNs
    with np.errstate(invalid="ignore"):
        columns = {
            name: np.asarray(records[name], dtype=np.float64)
            if records.dtype[name].base.kind == "f"
            else np.asarray(records[name])
            for name in names
        }
    return cloud_from_columns("PointCloud2", columns)


# --------------------------------------------------------------------------- ROS 1 walker


@dataclass(frozen=True)
class _Connection:
    conn: int
    topic: str
    msgtype: str  # ROS 2 spelling: pkg/msg/Name
    md5sum: str


@dataclass(frozen=True)
class _RawMessage:
    topic: str
    msgtype: str
    bag_time_ns: int
    data: bytes | memoryview
    index: int  # 0-based, per topic


_U32 = struct.Struct("<I")


def _header_fields(path: Path, raw: bytes, where: int) -> dict[str, bytes]:
    fields: dict[str, bytes] = {}
    pos, end = 0, len(raw)
    while pos < end:
        if pos + 4 > end:
            raise FileFormatError(path, f"corrupt record header at byte {where}")
        (size,) = _U32.unpack_from(raw, pos)
        pos += 4
        if pos + size > end:
            raise FileFormatError(path, f"corrupt record header at byte {where}")
        item = raw[pos : pos + size]
        pos += size
        key, sep, value = item.partition(b"=")
        if not sep:
            raise FileFormatError(path, f"corrupt record header field at byte {where}")
        fields[key.decode("ascii", "replace")] = value
    return fields


def _u32(path: Path, fields: dict[str, bytes], key: str, where: int) -> int:
    value = fields.get(key)
    if value is None or len(value) != 4:
        raise FileFormatError(path, f"record at byte {where}: missing or bad {key!r} field")
    return int(struct.unpack("<I", value)[0])


def _op(path: Path, fields: dict[str, bytes], where: int) -> int:
    op = fields.get("op")
    if op is None or len(op) != 1:
        raise FileFormatError(path, f"record at byte {where}: missing op field")
    return op[0]


class _Records:
    """Records ``(op, header fields, data, offset)`` of a byte stream in the bag's framing."""

    def __init__(self, path: Path, stream: BinaryIO, start: int, end: int) -> None:
        self.path, self.stream, self.pos, self.end = path, stream, start, end

    def _read(self, size: int, what: str, where: int) -> bytes:
        # check against the known size first: a corrupt length must not allocate gigabytes
        if self.pos + size > self.end:
            raise FileFormatError(
                self.path, f"truncated: {what} of the record at byte {where} ends past the data"
            )
        chunk = self.stream.read(size)
        if len(chunk) != size:
            raise FileFormatError(
                self.path, f"truncated: {what} of the record at byte {where} ends past the file"
            )
        self.pos += size
        return chunk

    def __iter__(self) -> Iterator[tuple[int, dict[str, bytes], bytes, int]]:
        while self.pos < self.end:
            where = self.pos
            (hlen,) = struct.unpack("<I", self._read(4, "the header length", where))
            if hlen > _MAX_HEADER:
                raise FileFormatError(
                    self.path, f"corrupt record at byte {where}: header length {hlen}"
                )
            header = _header_fields(self.path, self._read(hlen, "the header", where), where)
            (dlen,) = struct.unpack("<I", self._read(4, "the data length", where))
            op = _op(self.path, header, where)
            if op == _OP_INDEX:
                # Index data (version 1) holds ``count`` entries of 12 bytes (time, offset).
                # Some writers declare a different data length (the CCNY demo bag: 20 bytes
                # per entry, with 12-byte entries actually written), so the spec's size wins.
                dlen = 12 * _u32(self.path, header, "count", where)
            data = self._read(dlen, "the data", where)
            yield op, header, data, where


def _msgtype_ros2(name: str) -> str:
    parts = name.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else name


def _ros1_connection(path: Path, header: dict[str, bytes], data: bytes, where: int) -> _Connection:
    conn = _u32(path, header, "conn", where)
    info = _header_fields(path, data, where)
    try:
        topic = (info.get("topic") or header.get("topic") or b"").decode()
        msgtype = info["type"].decode()
        md5sum = info.get("md5sum", b"").decode()
    except (KeyError, UnicodeDecodeError):
        raise FileFormatError(path, f"connection record at byte {where} is corrupt") from None
    return _Connection(conn, topic, _msgtype_ros2(msgtype), md5sum)


def _decompress(path: Path, header: dict[str, bytes], data: bytes, where: int) -> bytes:
    compression = header.get("compression", b"none").decode("ascii", "replace")
    size = _u32(path, header, "size", where)
    try:
        if compression == "none":
            out = data
        elif compression == "bz2":
            # never more than the declared size + 1 byte: a corrupt chunk cannot balloon
            out = bz2.BZ2Decompressor().decompress(data, max_length=size + 1)
        elif compression == "lz4":
            import lz4.frame  # type: ignore[import-untyped]  # a dependency of rosbags

            out = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
        else:
            raise FileFormatError(path, f"chunk at byte {where}: unknown compression {compression}")
    except (OSError, ValueError, RuntimeError, EOFError) as exc:
        if isinstance(exc, FileFormatError):
            raise
        raise FileFormatError(path, f"chunk at byte {where}: cannot decompress: {exc}") from None
    if len(out) != size:
        raise FileFormatError(
            path, f"chunk at byte {where}: holds {len(out)} bytes, its header says {size}"
        )
    return out


class _Ros1Bag:
    """Walk a ROS 1 (format 2.0) bag: connections, chunk infos and messages in file order."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def _open(self) -> tuple[BinaryIO, int]:
        stream = self.path.open("rb")
        magic = stream.read(len(_ROS1_MAGIC))
        if magic != _ROS1_MAGIC:
            stream.close()
            if magic.startswith(b"#ROSBAG V"):
                version = magic.decode("ascii", "replace").strip()
                raise FileFormatError(self.path, f"unsupported bag version {version!r} (need 2.0)")
            raise FileFormatError(self.path, "not a ROS 1 bag (no '#ROSBAG V2.0' line)")
        return stream, len(_ROS1_MAGIC)

    def walk(
        self, wanted: set[str] | None
    ) -> Iterator[tuple[_Connection, int, bytes | memoryview]]:
        """Yield ``(connection, bag_time_ns, data)`` for messages on ``wanted`` topics (None: all).

        Connections are learned from the connection records that precede their messages
        inside the chunks; index-data records are skipped by their declared length only.
        At the end, the message counts are checked against the chunk-info records.
        """
        path = self.path
        stream, start = self._open()
        with stream:
            records = iter(_Records(path, stream, start, os.fstat(stream.fileno()).st_size))
            first = next(records, None)
            if first is None or first[0] != _OP_BAG_HEADER:
                raise FileFormatError(path, "the first record is not the bag header")
            connections: dict[int, _Connection] = {}
            counted: dict[int, int] = {}
            declared: dict[int, int] = {}
            has_chunk_info = False
            for op, header, data, where in records:
                if op == _OP_CHUNK:
                    payload = _decompress(path, header, data, where)
                    inner = _Records(path, io.BytesIO(payload), 0, len(payload))
                    for iop, ihead, idata, iwhere in inner:
                        at = where + iwhere
                        if iop == _OP_CONNECTION:
                            c = _ros1_connection(path, ihead, idata, at)
                            connections.setdefault(c.conn, c)
                        elif iop == _OP_MESSAGE:
                            conn = _u32(path, ihead, "conn", at)
                            if conn not in connections:
                                raise FileFormatError(
                                    path, f"message at byte {at} uses unknown connection {conn}"
                                )
                            stamp = ihead.get("time")
                            if stamp is None or len(stamp) != 8:
                                raise FileFormatError(path, f"message at byte {at}: bad time")
                            sec, nsec = struct.unpack("<II", stamp)
                            counted[conn] = counted.get(conn, 0) + 1
                            c = connections[conn]
                            if wanted is None or c.topic in wanted:
                                yield c, sec * 1_000_000_000 + nsec, idata
                        else:
                            raise FileFormatError(
                                path, f"chunk at byte {where}: unexpected record op {iop:#04x}"
                            )
                elif op == _OP_CONNECTION:
                    c = _ros1_connection(path, header, data, where)
                    connections.setdefault(c.conn, c)
                elif op == _OP_CHUNK_INFO:
                    has_chunk_info = True
                    if len(data) % 8:
                        raise FileFormatError(path, f"chunk info at byte {where} is corrupt")
                    pairs = np.frombuffer(data, dtype="<u4").reshape(-1, 2)
                    for conn, count in pairs.tolist():
                        declared[conn] = declared.get(conn, 0) + count
                elif op in (_OP_INDEX, _OP_BAG_HEADER):
                    continue  # index data: never trusted (see the module docstring)
                else:
                    raise FileFormatError(path, f"unknown record op {op:#04x} at byte {where}")
            if has_chunk_info and declared != counted:
                raise FileFormatError(
                    path,
                    f"message counts per connection {counted} differ from the index's {declared} "
                    "(truncated or corrupt bag)",
                )

    def connections(self) -> list[tuple[_Connection, int]]:
        """Every connection with its message count (one pass over the file)."""
        counts: dict[int, int] = {}
        seen: dict[int, _Connection] = {}
        for c, _, _ in self.walk(None):
            counts[c.conn] = counts.get(c.conn, 0) + 1
            seen[c.conn] = c
        # connections without messages still exist: learn them from a second light pass
        for c in self._all_connections():
            seen.setdefault(c.conn, c)
        return [(seen[k], counts.get(k, 0)) for k in sorted(seen)]

    def _all_connections(self) -> list[_Connection]:
        """The connection records: from the index section when the bag header points to a
        readable one (no chunk is read), else from a walk over the whole file."""
        stream, start = self._open()
        size = os.fstat(stream.fileno()).st_size
        with stream:
            records = iter(_Records(self.path, stream, start, size))
            first = next(records, None)
            if first is None or first[0] != _OP_BAG_HEADER:
                raise FileFormatError(self.path, "the first record is not the bag header")
            index_pos = first[1].get("index_pos", b"")
            pos = struct.unpack("<Q", index_pos)[0] if len(index_pos) == 8 else 0
            after_header = stream.tell()
            if start < pos < size:
                stream.seek(pos)
                try:
                    found = self._connection_records(_Records(self.path, stream, pos, size))
                except FileFormatError:
                    found = []  # a damaged index section: the walk below decides
                if found:
                    return found
            stream.seek(after_header)
            return self._connection_records(_Records(self.path, stream, after_header, size))

    def _connection_records(self, records: _Records) -> list[_Connection]:
        return [
            _ros1_connection(self.path, header, data, where)
            for op, header, data, where in records
            if op == _OP_CONNECTION
        ]


# --------------------------------------------------------------------------- ROS 2


def _is_ros1(path: Path) -> bool:
    if path.is_dir():
        return False
    with path.open("rb") as f:
        return f.read(9) == b"#ROSBAG V"


def _ros2_reader(path: Path) -> Any:
    _rosbags()
    from rosbags.rosbag2 import Reader

    try:
        reader = Reader(path)
        reader.open()
    except FileNotFoundError:
        raise
    except Exception as exc:  # rosbags raises its own ReaderError, sqlite3/mcap errors, …
        raise FileFormatError(path, f"cannot open as a ROS 2 bag: {exc}") from None
    return reader


def _ros2_connections(path: Path) -> list[tuple[_Connection, int]]:
    reader = _ros2_reader(path)
    try:
        return [
            (_Connection(c.id, c.topic, c.msgtype, ""), int(c.msgcount)) for c in reader.connections
        ]
    finally:
        reader.close()


def _ros2_messages(
    path: Path, choose: Callable[[set[tuple[str, str]]], str]
) -> Iterator[tuple[_Connection, int, bytes | memoryview]]:
    """The messages of the topic ``choose`` picks from the bag's ``(topic, msgtype)`` pairs,
    from one open of the bag (an open of a sqlite3 bag costs ~2 ms: the topic is chosen from
    the connections of the same open)."""
    reader = _ros2_reader(path)
    messages = None
    try:
        topic = choose({(c.topic, c.msgtype) for c in reader.connections})
        conns = [c for c in reader.connections if c.topic == topic]
        by_id = {c.id: _Connection(c.id, c.topic, c.msgtype, "") for c in conns}
        if not conns:
            return
        messages = reader.messages(connections=conns)
        while True:
            try:
                item = next(messages)
            except StopIteration:
                return
            except Exception as exc:  # corrupt sqlite pages, truncated mcap records, …
                raise FileFormatError(path, f"cannot read messages: {exc}") from None
            conn, stamp, data = item
            yield by_id[conn.id], int(stamp), data
    finally:
        # The message generator holds an sqlite3 statement: closing the database under it
        # raised "database is locked" when a caller stopped early, e.g. on a corrupt message
        # (found by fuzz/, ros2_sqlite).
        if messages is not None:
            messages.close()
        reader.close()


# --------------------------------------------------------------------------- public API


def _check_path(path: PathLike) -> Path:
    if not isinstance(path, (str, Path)) and not hasattr(path, "__fspath__"):
        raise TypeError(f"path: expected a str or os.PathLike, got {type(path).__name__}")
    p = path if isinstance(path, Path) else Path(path)
    try:
        st = os.stat(p)  # one stat for "exists", "is a file" and "is empty"
    except OSError as exc:
        if exc.errno not in (errno.ENOENT, errno.ENOTDIR, errno.ELOOP):  # as Path.exists()
            raise
        raise FileNotFoundError(f"{p}: no such file or directory") from None
    if stat.S_ISREG(st.st_mode) and st.st_size == 0:
        raise FileFormatError(p, "empty file")
    return p


def _connections(path: Path) -> list[tuple[_Connection, int]]:
    return _Ros1Bag(path).connections() if _is_ros1(path) else _ros2_connections(path)


def list_topics(path: PathLike) -> tuple[BagTopic, ...]:
    """Every topic of a ROS 1 or ROS 2 bag with its type and message count, sorted by name.

    For ROS 1 bags the counts are those of the messages actually found in the chunks (the
    whole file is read once).
    """
    p = _check_path(path)
    totals: dict[tuple[str, str], int] = {}
    for c, n in _connections(p):
        totals[(c.topic, c.msgtype)] = totals.get((c.topic, c.msgtype), 0) + n
    return tuple(BagTopic(t, m, n) for (t, m), n in sorted(totals.items()))


def _choose_topic(path: Path, topics: set[tuple[str, str]], topic: str | None, msgtype: str) -> str:
    """The ``msgtype`` topic to read among the bag's ``(topic, msgtype)`` pairs."""
    matching = sorted({t for t, m in topics if m == msgtype})
    if topic is not None:
        if not isinstance(topic, str):
            raise TypeError(f"topic: expected a str, got {type(topic).__name__}")
        types = {m for t, m in topics if t == topic}
        if not types:
            known = ", ".join(sorted({t for t, _ in topics})) or "none"
            raise ValueError(f"topic: {path} has no topic {topic!r} (topics: {known})")
        if msgtype not in types:
            raise ValueError(f"topic: {topic!r} in {path} is {sorted(types)[0]}, not {msgtype}")
        return topic
    if not matching:
        known = ", ".join(f"{t} ({m})" for t, m in sorted(topics)) or "none"
        raise ValueError(f"{path}: no {msgtype} topic (topics: {known})")
    if len(matching) > 1:
        raise ValueError(
            f"topic: {path} has several {msgtype} topics ({', '.join(matching)}); choose one"
        )
    return matching[0]


@functools.cache
def _typestore(ros1: bool) -> Any:
    """One rosbags typestore per process and ROS version: a new store compiles its
    (de)serialisers again on first use, which cost ~25 ms per bag read (measured by fuzz/)."""
    rosbags = _rosbags()
    stores = rosbags.typesys.Stores
    store = rosbags.typesys.get_typestore(stores.ROS1_NOETIC if ros1 else stores.LATEST)
    if ros1 and "tf2_msgs/msg/TFMessage" not in store.types:
        # rosbags' Noetic store lacks tf2_msgs (a LaserScan bag's /tf and /tf_static); this
        # definition has the message's ROS 1 md5, 94810edda583a504dfda3829e70d7eec.
        text = "geometry_msgs/TransformStamped[] transforms"
        for name in ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage"):
            store.register(rosbags.typesys.get_types_from_msg(text, name))
    return store


@functools.cache
def _ros1_md5(msgtype: str) -> str:
    """The md5 sum of a ROS 1 message definition (rosbags regenerates the definition text on
    every call: ~0.7 ms per bag read, measured by fuzz/)."""
    return str(_typestore(True).generate_msgdef(msgtype)[1])


def _deserialise(path: Path, data: bytes | memoryview, msgtype: str, ros1: bool, where: str) -> Any:
    """One message's bytes (ROS 1 serialisation or CDR) as a rosbags message object."""
    store = _typestore(ros1)
    try:
        return (store.deserialize_ros1 if ros1 else store.deserialize_cdr)(data, msgtype)
    except Exception as exc:  # rosbags raises struct/index/assertion errors on bad bytes
        raise FileFormatError(path, f"{where}: cannot deserialise {msgtype}: {exc!r}") from None


def _deserialised(
    path: Path, topic: str | None, msgtype: str
) -> Iterator[tuple[_Connection, int, Any, int]]:
    """The messages of the chosen ``msgtype`` topic (see :func:`_choose_topic`), decoded."""
    _rosbags()  # the message naming the extra, even when a store is cached
    ros1 = _is_ros1(path)
    messages: Iterator[tuple[_Connection, int, bytes | memoryview]]
    if ros1:
        bag = _Ros1Bag(path)
        topics = {(c.topic, c.msgtype) for c in bag._all_connections()}
        chosen = _choose_topic(path, topics, topic, msgtype)
        md5 = _ros1_md5(msgtype)
        messages = bag.walk({chosen})
    else:
        chosen = ""  # set by the choice below, made on the bag's one open

        def choose(topics: set[tuple[str, str]]) -> str:
            nonlocal chosen
            chosen = _choose_topic(path, topics, topic, msgtype)
            return chosen

        messages = _ros2_messages(path, choose)
    for index, (conn, stamp, data) in enumerate(messages):
        if conn.msgtype != msgtype:
            continue
        if ros1 and conn.md5sum and conn.md5sum != md5:
            raise FileFormatError(
                path, f"{chosen}: message definition md5 {conn.md5sum} is not {msgtype}'s {md5}"
            )
        msg = _deserialise(path, data, msgtype, ros1, f"{chosen} message {index}")
        yield conn, stamp, msg, index


def _stamp(msg: Any) -> float:
    # integer nanoseconds, divided once: the float nearest the stamp (sec + 1e-9·nanosec
    # rounds twice, one unit of 2.4e-7 s off for a 2009 stamp)
    stamp = msg.header.stamp
    return (int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)) / 1_000_000_000


def _scan_from_message(path: Path, topic: str, stamp: int, msg: Any, index: int) -> RosLaserScan:
    """A deserialised ``sensor_msgs/LaserScan`` as a :class:`RosLaserScan` (``stamp``: the
    bag's receive time, ns); an inconsistent message is a :class:`FileFormatError`."""
    with np.errstate(invalid="ignore"):  # signalling NaNs are read as NaN
        ranges = np.asarray(msg.ranges, dtype=np.float64)
        inten = np.asarray(msg.intensities, dtype=np.float64)
    n = ranges.shape[0]
    where = f"{topic} message {index}"
    values = (msg.angle_min, msg.angle_increment, msg.range_max, msg.range_min)
    if not np.isfinite(values).all():
        raise FileFormatError(path, f"{where}: non-finite angle_min/increment or range limits")
    if not msg.range_max > 0:
        raise FileFormatError(path, f"{where}: range_max must be > 0, got {msg.range_max}")
    if inten.size not in (0, n):
        raise FileFormatError(path, f"{where}: {inten.size} intensities for {n} ranges")
    angles = float(msg.angle_min) + float(msg.angle_increment) * np.arange(n, dtype=np.float64)
    try:
        return RosLaserScan(
            kind="sensor_msgs/LaserScan",
            ranges=ranges,
            angles=angles,
            max_range=float(msg.range_max),
            laser_pose=None,
            odometry_pose=None,
            timestamp=_stamp(msg),
            logger_timestamp=stamp * 1e-9,
            topic=topic,
            frame_id=str(msg.header.frame_id),
            range_min=max(float(msg.range_min), 0.0),
            intensities=inten if inten.size else None,
            time_increment=float(msg.time_increment),
            scan_time=float(msg.scan_time),
            angle_increment=float(msg.angle_increment),
        )
    except ValueError as exc:
        raise FileFormatError(path, f"{where}: {exc}") from None


def _cloud_from_message(path: Path, topic: str, stamp: int, msg: Any, index: int) -> BagCloud:
    """A deserialised ``sensor_msgs/PointCloud2`` as a :class:`BagCloud` (``stamp``: the bag's
    receive time, ns); an inconsistent message is a :class:`FileFormatError`."""
    try:
        cloud = decode_pointcloud2(
            msg.fields,
            msg.data,
            height=int(msg.height),
            width=int(msg.width),
            point_step=int(msg.point_step),
            row_step=int(msg.row_step),
            is_bigendian=bool(msg.is_bigendian),
        )
    except (ValueError, TypeError) as exc:
        raise FileFormatError(path, f"{topic} message {index}: {exc}") from None
    return BagCloud(
        cloud=cloud,
        timestamp=_stamp(msg),
        bag_time=stamp * 1e-9,
        topic=topic,
        frame_id=str(msg.header.frame_id),
        height=int(msg.height),
        width=int(msg.width),
        is_dense=bool(msg.is_dense),
    )


def iter_bag_scans(path: PathLike, topic: str | None = None) -> Iterator[RosLaserScan]:
    """Yield the ``sensor_msgs/LaserScan`` messages of ``topic`` one at a time, in bag order.

    ``topic`` may be omitted when the bag has exactly one LaserScan topic.
    """
    p = _check_path(path)
    for conn, stamp, msg, index in _deserialised(p, topic, LASER_SCAN):
        yield _scan_from_message(p, conn.topic, stamp, msg, index)


def read_bag_scans(path: PathLike, topic: str | None = None) -> list[RosLaserScan]:
    """Every ``sensor_msgs/LaserScan`` of ``topic`` (see :func:`iter_bag_scans`)."""
    return list(iter_bag_scans(path, topic))


def iter_bag_clouds(path: PathLike, topic: str | None = None) -> Iterator[BagCloud]:
    """Yield the ``sensor_msgs/PointCloud2`` messages of ``topic`` one at a time, in bag order.

    ``topic`` may be omitted when the bag has exactly one PointCloud2 topic.
    """
    p = _check_path(path)
    for conn, stamp, msg, index in _deserialised(p, topic, POINT_CLOUD2):
        yield _cloud_from_message(p, conn.topic, stamp, msg, index)


def read_bag_clouds(path: PathLike, topic: str | None = None) -> list[BagCloud]:
    """Every ``sensor_msgs/PointCloud2`` of ``topic`` (see :func:`iter_bag_clouds`)."""
    return list(iter_bag_clouds(path, topic))


__all__ = [
    "LASER_SCAN",
    "POINTFIELD_DTYPES",
    "POINT_CLOUD2",
    "BagCloud",
    "BagTopic",
    "RosLaserScan",
    "decode_pointcloud2",
    "iter_bag_clouds",
    "iter_bag_scans",
    "list_topics",
    "read_bag_clouds",
    "read_bag_scans",
]
