"""Log and parameter tables of contents (TOC V2), as cflib downloads them, and their value encodings.

Takes in: the variables a vehicle offers, as TocEntry(group, name, type name[, read-only]).
Gives out: the TOC's info reply (count, CRC), each item's reply, and value packing by type name.

Wire (cflib log.py / param.py / toc.py, firmware log.c / param_logic.c):
- info request `03` -> `03 <u16 count> <u32 crc>` (+ for the log: max blocks 16, max ops 128);
- item request `02 <u16 index>` -> `02 <u16 index> <type byte> group\\0 name\\0`, or `02` alone when the
  index is out of range. The CRC keys cflib's TOC cache: here a CRC-32 of the contents, so a changed TOC
  invalidates a client's cache.
Log type ids: 1 uint8 ... 7 float (log.py LogTocElement.types); param type bytes: 0x08 uint8,
0x09 uint16, 0x0A uint32, 0x00 int8, 0x01 int16, 0x02 int32, 0x06 float, | 0x40 read-only (never the 0x10
"extended" flag, which would make cflib ask for extended types).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

# name -> (log type id, param type byte, struct format)
TYPES = {
    "uint8_t": (1, 0x08, "<B"), "uint16_t": (2, 0x09, "<H"), "uint32_t": (3, 0x0A, "<I"),
    "int8_t": (4, 0x00, "<b"), "int16_t": (5, 0x01, "<h"), "int32_t": (6, 0x02, "<i"),
    "float": (7, 0x06, "<f"),
}
LOG_TYPE_NAMES = {log_id: name for name, (log_id, _, _) in TYPES.items()}
PARAM_READ_ONLY = 0x40
CMD_TOC_ITEM = 2
CMD_TOC_INFO = 3
LOG_MAX_BLOCKS = 16  # firmware log.c LOG_MAX_BLOCKS
LOG_MAX_OPS = 128  # firmware log.c LOG_MAX_OPS
MAX_NAME_BYTES = 24  # group + name: a TOC item reply must fit in 30 bytes


@dataclass(frozen=True)
class TocEntry:
    group: str
    name: str
    type_name: str  # a key of TYPES
    read_only: bool = False

    @property
    def full_name(self) -> str:
        return f"{self.group}.{self.name}"

    def pack(self, value: float | int) -> bytes:
        fmt = TYPES[self.type_name][2]
        return struct.pack(fmt, value if fmt == "<f" else int(value))

    def unpack(self, data: bytes) -> float | int | None:
        """The value in data (exactly its size), None when the size is wrong."""
        fmt = TYPES[self.type_name][2]
        return struct.unpack(fmt, data)[0] if len(data) == struct.calcsize(fmt) else None


class Toc:
    """An ordered TOC of one kind ("log" or "param")."""

    def __init__(self, kind: str, entries: list[TocEntry]):
        self.kind = kind
        self.entries = list(entries)
        for entry in self.entries:
            if entry.type_name not in TYPES:
                raise ValueError(f"{kind} TOC {entry.full_name}: unknown type {entry.type_name}")
            if len(entry.group) + len(entry.name) > MAX_NAME_BYTES:
                raise ValueError(f"{kind} TOC {entry.full_name}: name too long for a CRTP packet")
        self.index = {entry.full_name: i for i, entry in enumerate(self.entries)}
        text = ";".join(f"{e.full_name}:{e.type_name}:{int(e.read_only)}" for e in self.entries)
        self.crc = zlib.crc32(f"{kind}|{text}".encode())

    def info(self) -> bytes:
        extra = bytes((LOG_MAX_BLOCKS, LOG_MAX_OPS)) if self.kind == "log" else b""
        return struct.pack("<BHI", CMD_TOC_INFO, len(self.entries), self.crc) + extra

    def item(self, index: int) -> bytes:
        if not 0 <= index < len(self.entries):
            return bytes((CMD_TOC_ITEM,))
        entry = self.entries[index]
        log_id, param_byte, _ = TYPES[entry.type_name]
        type_byte = log_id if self.kind == "log" else param_byte | (PARAM_READ_ONLY if entry.read_only else 0)
        return (struct.pack("<BHB", CMD_TOC_ITEM, index, type_byte)
                + entry.group.encode() + b"\0" + entry.name.encode() + b"\0")
