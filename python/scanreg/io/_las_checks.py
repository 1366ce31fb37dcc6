"""What a LAS/LAZ file claims, checked against its size before laspy and lazrs trust it.

laspy allocates ``point count × record length`` and loops over the VLR count; lazrs reserves
one entry per chunk the chunk table claims and a buffer per chunk's point count. A damaged
field there made laspy loop for minutes, or lazrs abort the whole interpreter ("memory
allocation of 34359738352 bytes failed", SIGABRT: nothing to catch). Every such count is
bounded here by the bytes that could hold it; a file that fails raises
:class:`FileFormatError` naming the field.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import Any, BinaryIO

from ._common import FileFormatError

#: Smallest public header block (LAS 1.0-1.2) and its LAS 1.4 size.
MIN_HEADER, HEADER_14 = 227, 375
#: A variable-length record's header; an extended VLR's (LAS 1.4).
VLR_HEADER, EVLR_HEADER = 54, 60
#: Byte of the public header block that holds the point data record format.
POINT_FORMAT_BYTE = 104
#: Bits 6 and 7 of that byte flag LAZ compression (laszip's convention).
COMPRESSION_BITS = 0xC0
#: Core record size of each point format 0-10 (extra bytes come on top).
MIN_RECORD = (20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67)
#: A LAZ file larger than this many times its compressed point data is not believed.
MAX_LAZ_RATIO = 200
#: laszip's VLR (user id, record id), and its "variable-size chunks" chunk size.
LASZIP_VLR = (b"laszip encoded", 22204)
VARIABLE_CHUNKS = 0xFFFFFFFF
#: Bytes lazrs may reserve for one chunk's decompressed points whatever the file's size.
MAX_CHUNK_BYTES = 1 << 28
#: A chunk-table entry needs at least this many bytes of compressed points (a chunk starts
#: with one raw point record of >= 20 bytes; 8 leaves room).
MIN_CHUNK_BYTES = 8
#: The laszip items ``(type, bytes)`` of each point format 0-10, as laszip and lazrs write
#: them (POINT10 6, GPSTIME11 7, RGB12 8, WAVEPACKET13 9; POINT14 10, RGB14 11, RGBNIR14 12,
#: WAVEPACKET14 13); extra bytes add one BYTE (0) or, for formats 6-10, BYTE14 (14) item.
POINT_ITEMS: tuple[tuple[tuple[int, int], ...], ...] = (
    ((6, 20),),
    ((6, 20), (7, 8)),
    ((6, 20), (8, 6)),
    ((6, 20), (7, 8), (8, 6)),
    ((6, 20), (7, 8), (9, 29)),
    ((6, 20), (7, 8), (8, 6), (9, 29)),
    ((10, 30),),
    ((10, 30), (11, 6)),
    ((10, 30), (12, 8)),
    ((10, 30), (13, 29)),
    ((10, 30), (12, 8), (13, 29)),
)
BYTE, BYTE14 = 0, 14


def check_las_file(path: Path) -> None:
    """Raise :class:`FileFormatError` when the header's counts, offsets or record length
    (and, for LAZ, the laszip VLR and the chunk table) do not fit the file's size."""
    size = path.stat().st_size
    with path.open("rb") as fh:
        head = fh.read(HEADER_14)
        if head[:4] != b"LASF":
            raise FileFormatError(path, "not a LAS/LAZ file (no 'LASF' signature)")
        if len(head) < MIN_HEADER:
            raise FileFormatError(path, f"truncated header ({len(head)} of {MIN_HEADER} bytes)")
        header_size, offset, n_vlrs = struct.unpack_from("<HII", head, 94)
        fmt_byte, record_length, legacy_count = struct.unpack_from("<BHI", head, POINT_FORMAT_BYTE)
        fmt = fmt_byte & ~COMPRESSION_BITS & 0xFF
        if fmt > 10:
            raise FileFormatError(
                path, f"unknown LAS point format {fmt} (LAS 1.4 defines formats 0-10)"
            )
        if record_length < MIN_RECORD[fmt]:
            raise FileFormatError(
                path,
                f"point data record length {record_length} is shorter than point format "
                f"{fmt}'s {MIN_RECORD[fmt]} bytes",
            )
        las14 = head[25] >= 4 and header_size >= HEADER_14 and len(head) >= HEADER_14
        count = legacy_count
        if las14:
            count = max(count, struct.unpack_from("<Q", head, 247)[0])
        if not MIN_HEADER <= header_size <= offset <= size:
            raise FileFormatError(
                path,
                f"corrupt header: header size {header_size}, offset to point data {offset}, "
                f"file {size} bytes",
            )
        if n_vlrs * VLR_HEADER > offset - header_size:
            raise FileFormatError(
                path, f"corrupt header: number of VLRs {n_vlrs} do not fit before the points"
            )
        if las14:
            _check_evlrs(path, head, size)
        _check_scale_offset(path, head)
        data = size - offset
        if not fmt_byte & COMPRESSION_BITS:
            if count * record_length > data:
                raise FileFormatError(
                    path,
                    f"truncated: point count {count} of {record_length} bytes needs "
                    f"{count * record_length} bytes, the file has {data} after the header",
                )
            return
        if count * record_length > MAX_LAZ_RATIO * data + (1 << 20):
            raise FileFormatError(
                path, f"corrupt header: point count {count} cannot be in {data} compressed bytes"
            )
        vlr, body = _laszip_vlr(path, fh, header_size, n_vlrs, record_length)
        _check_items(path, body, fmt, record_length)
        entries = _check_chunk_table(path, fh, vlr, size, offset, count, record_length)
        _check_layered_chunks(path, fh, body, entries, offset + 8, record_length)


def _check_scale_offset(path: Path, head: bytes) -> None:
    """``x = X·scale + offset`` for any int32 ``X`` must be a finite float: laspy computes it
    for every point (a scale of -1.8e305 overflowed, numpy's "overflow encountered")."""
    scales = struct.unpack_from("<3d", head, 131)
    offsets = struct.unpack_from("<3d", head, 155)
    for axis, scale, offset in zip("xyz", scales, offsets, strict=True):
        reach = abs(scale) * 2.0**31 + abs(offset)
        if scale == 0 or not math.isfinite(reach):
            raise FileFormatError(
                path,
                f"corrupt header: {axis} scale factor {scale!r} and offset {offset!r} do not "
                "make finite coordinates",
            )


def _check_evlrs(path: Path, head: bytes, size: int) -> None:
    start, n = struct.unpack_from("<QI", head, 235)
    if n and (start > size or n * EVLR_HEADER > size - start):
        raise FileFormatError(
            path, f"corrupt header: {n} extended VLRs at byte {start} do not fit in {size} bytes"
        )


def _laszip_vlr(
    path: Path, fh: BinaryIO, at: int, n_vlrs: int, record_length: int
) -> tuple[Any, bytes]:
    """The laszip VLR as lazrs reads it, and its bytes (its item sizes must make up the
    point record)."""
    import lazrs

    fh.seek(at)
    for _ in range(n_vlrs):
        vlr_head = fh.read(VLR_HEADER)
        if len(vlr_head) < VLR_HEADER:
            raise FileFormatError(path, "truncated VLR header")
        user_id = vlr_head[2:18].rstrip(b"\0")
        record_id, length = struct.unpack_from("<HH", vlr_head, 18)
        body = fh.read(length)
        if (user_id, record_id) != LASZIP_VLR:
            continue
        try:
            vlr = lazrs.LazVlr(body)
            item_size = int(vlr.item_size())
        except Exception as exc:  # lazrs.LazrsError, struct errors of a short record
            raise FileFormatError(path, f"corrupt laszip VLR: {exc}") from None
        if item_size != record_length:
            raise FileFormatError(
                path,
                f"laszip VLR items make {item_size}-byte points, the header's point data "
                f"record length is {record_length}",
            )
        return vlr, body
    raise FileFormatError(path, "compressed point data (LAZ) without a laszip VLR")


def _check_items(path: Path, body: bytes, fmt: int, record_length: int) -> None:
    """The laszip VLR's items must be those of the header's point format: lazrs decodes by
    the items, laspy reads the points by the format. An RGB14 item of 30 bytes where POINT14
    belonged (one byte changed in a 1.5 kB file) made lazrs take 2.6 s and 2 GB before
    refusing it (found by fuzz/, target laz)."""
    (n_items,) = struct.unpack_from("<H", body, 32)
    if len(body) < 34 + 6 * n_items:
        raise FileFormatError(path, f"corrupt laszip VLR: {n_items} items in {len(body)} bytes")
    items = tuple(struct.unpack_from("<HH", body, 34 + 6 * k) for k in range(n_items))
    expected = POINT_ITEMS[fmt]
    if extra := record_length - MIN_RECORD[fmt]:
        expected += ((BYTE14 if fmt >= 6 else BYTE, extra),)
    if items != expected:
        raise FileFormatError(
            path,
            f"laszip VLR items (type, bytes) {list(items)} are not point format {fmt}'s "
            f"{list(expected)}",
        )


def _check_chunk_table(
    path: Path, fh: BinaryIO, vlr: Any, size: int, offset: int, count: int, record_length: int
) -> list[tuple[int, int]]:
    """The chunk table's entry count, point counts and byte counts against the file: lazrs
    reserves memory for each before reading a point. Returns its ``(points, bytes)``
    entries."""
    import lazrs

    chunk_size = int(vlr.chunk_size())
    variable = chunk_size == VARIABLE_CHUNKS
    if chunk_size == 0:
        raise FileFormatError(path, "laszip VLR chunk size 0")
    if not variable and chunk_size * record_length > max(MAX_CHUNK_BYTES, count * record_length):
        raise FileFormatError(
            path, f"laszip VLR chunk size {chunk_size} points is beyond the file's {count} points"
        )
    fh.seek(offset)
    raw = fh.read(8)
    if len(raw) < 8:
        raise FileFormatError(path, "truncated: no LAZ chunk table offset after the header")
    table = struct.unpack("<q", raw)[0]
    if table <= offset:  # a streaming writer could not seek back: the offset ends the file
        fh.seek(max(size - 8, 0))
        table = struct.unpack("<q", fh.read(8))[0]
        if table <= offset:
            raise FileFormatError(path, "LAZ chunk table offset: no chunk table")
    if table + 8 > size:
        raise FileFormatError(
            path, f"LAZ chunk table offset {table} is past the end of the file ({size} bytes)"
        )
    fh.seek(table)
    _version, n_chunks = struct.unpack("<II", fh.read(8))
    points_bytes = table - offset - 8
    if n_chunks > max(count, 1) or n_chunks * MIN_CHUNK_BYTES > points_bytes:
        raise FileFormatError(
            path,
            f"corrupt LAZ chunk table: number of chunks {n_chunks} for {count} points in "
            f"{points_bytes} compressed bytes",
        )
    fh.seek(table)
    try:
        entries = lazrs.read_chunk_table_only(fh, vlr)
    except Exception as exc:  # lazrs.LazrsError: the table runs past the end of the file
        raise FileFormatError(path, f"corrupt LAZ chunk table: {exc}") from None
    byte_total = sum(int(b) for _, b in entries)
    if byte_total > points_bytes:
        raise FileFormatError(
            path,
            f"corrupt LAZ chunk table: its chunks hold {byte_total} bytes, the points "
            f"{points_bytes}",
        )
    if variable:
        counts = [int(p) for p, _ in entries]
        if any(not 0 < p <= max(count, 1) for p in counts) or (count and sum(counts) < count):
            raise FileFormatError(
                path,
                f"corrupt LAZ chunk table: chunk point counts do not make the header's "
                f"{count} points",
            )
    elif len(entries) * chunk_size < count:
        raise FileFormatError(
            path,
            f"corrupt LAZ chunk table: {len(entries)} chunks of {chunk_size} points cannot hold "
            f"the header's {count} points",
        )
    return [(int(p), int(b)) for p, b in entries]


#: laszip's compressor id of the layered chunks of point formats 6-10, and how many layers
#: (one byte count each) each of its item types has: POINT14 9 (xy, z, classification,
#: flags, intensity, scan angle, user data, point source, GPS time), RGB14 1, RGBNIR14 2,
#: WAVEPACKET14 1, BYTE14 one per byte.
LAYERED_COMPRESSOR = 3
LAYERS = {10: 9, 11: 1, 12: 2, 13: 1}


def _check_layered_chunks(
    path: Path, fh: BinaryIO, body: bytes, entries: list[tuple[int, int]], start: int,
    record_length: int,
) -> None:  # fmt: skip
    """Each chunk of a layered LAZ (point formats 6-10) starts with one raw point, its point
    count and one byte count per layer; lazrs zero-fills a buffer of each layer's count before
    reading it (a 1.5 kB file claimed 4 GB layers: seconds of memset and gigabytes, and
    enough of them abort). Every layer's count must fit in its chunk."""
    (compressor,) = struct.unpack_from("<H", body, 0)
    (n_items,) = struct.unpack_from("<H", body, 32)
    if compressor != LAYERED_COMPRESSOR:
        return
    layers = 0
    for k in range(n_items):
        kind, size, _ = struct.unpack_from("<HHH", body, 34 + 6 * k)
        layers += size if kind == BYTE14 else LAYERS.get(kind, 0)
    head = record_length + 4 + 4 * layers
    at = start
    for index, (_, chunk_bytes) in enumerate(entries):
        fh.seek(at + record_length + 4)
        raw = fh.read(4 * layers)
        if len(raw) < 4 * layers or head > chunk_bytes:
            raise FileFormatError(path, f"corrupt LAZ chunk {index}: truncated layer sizes")
        total = sum(struct.unpack(f"<{layers}I", raw))
        if total > chunk_bytes - head:
            raise FileFormatError(
                path,
                f"corrupt LAZ chunk {index}: its layers claim {total} bytes, the chunk holds "
                f"{chunk_bytes - head}",
            )
        at += chunk_bytes
