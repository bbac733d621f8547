"""Prusa's binary G-code (`.bgcode`): its blocks, their checksums, and the G-code inside.

The format, as libbgcode's specification gives it (all integers little-endian):

- a 10-byte file header: `GCDE`, version (u32, 1), checksum type (u16: 0 none, 1 CRC32);
- blocks, each: type (u16), compression (u16: 0 none, 1 Deflate, 2 heatshrink 11/4,
  3 heatshrink 12/4), uncompressed size (u32), compressed size (u32, only when
  compressed); parameters (a u16 encoding; a thumbnail's are format, width, height);
  the data; a CRC32 of header, parameters and data when the file has checksums.
- Block types: 0 file metadata, 1 G-code, 2 slicer metadata, 3 printer metadata,
  4 print metadata, 5 thumbnail. Metadata is INI text (`key=value` lines); G-code is
  plain, MeatPack (1) or MeatPack keeping comment lines (2); a thumbnail is PNG (0),
  JPG (1) or QOI (2).

Reading is block by block (a G-code block holds at most 64 KiB of text), so a file
is never whole in memory: the stored file stays binary and the printer receives
the plain G-code as the stream reads on. Deflate is zlib; heatshrink is the
heatshrink2 library; MeatPack decoding is here (no kept library on the package
index decodes it block by block). Every error names the file and the block.
"""

from __future__ import annotations

import re
import struct
import zlib
from dataclasses import dataclass
from enum import IntEnum
from typing import TYPE_CHECKING

import heatshrink2

if TYPE_CHECKING:
    from collections.abc import Iterator
    from typing import Any, BinaryIO

__all__ = [
    "MAGIC",
    "BadBgcode",
    "BgcodeReader",
    "Block",
    "BlockType",
    "is_bgcode",
    "meatpack_decode",
    "metadata_of",
]

MAGIC = b"GCDE"
#: More than any block a slicer writes (G-code blocks hold 64 KiB, thumbnails less):
#: a size over this is a broken file, never a reason to allocate gigabytes. Deflate
#: stops at the promised size; heatshrink expands at most 8 times.
MAX_BLOCK_BYTES = 8 << 20
#: What a file may decode to: EXPANSION times the bytes read so far, plus
#: EXPANSION_SLACK. Slicers' files decode to a few times their size; a small file
#: that decodes to gigabytes is a bomb, whose every line the upload's check, the
#: analysis and the worker would read.
EXPANSION = 64
EXPANSION_SLACK = 64 << 20

_FILE_HEADER = struct.Struct("<4sIH")
_BLOCK_HEADER = struct.Struct("<HHI")
_U32 = struct.Struct("<I")


class BadBgcode(ValueError):
    """The binary G-code file is broken; the message says where and how."""


class BlockType(IntEnum):
    FILE_METADATA = 0
    GCODE = 1
    SLICER_METADATA = 2
    PRINTER_METADATA = 3
    PRINT_METADATA = 4
    THUMBNAIL = 5


_THUMBNAIL_FORMATS = {0: "PNG", 1: "JPG", 2: "QOI"}


@dataclass(frozen=True, slots=True)
class Block:
    """One block, checked and decompressed (G-code blocks also decoded to text)."""

    type: BlockType
    #: Where the block starts and ends in the file.
    start: int
    end: int
    #: The data: INI text, plain G-code, or an image.
    data: bytes
    #: A thumbnail's format ("PNG", "JPG", "QOI") and size.
    image: str = ""
    width: int = 0
    height: int = 0


def is_bgcode(head: bytes) -> bool:
    """The first bytes of a file say it is binary G-code."""
    return head[:4] == MAGIC


class BgcodeReader:
    """Reads the blocks of a binary G-code file from *handle*, in file order.

    *name* is the file's name for messages. With *digest* (a hashlib object) every
    byte read is hashed: the caller checks the stored file while it decodes it.
    """

    def __init__(
        self, handle: BinaryIO, *, name: str = "file", digest: Any = None
    ) -> None:
        self._handle = handle
        self._name = name
        self._digest = digest
        self._offset = 0
        self._decoded = 0
        head = self._read(_FILE_HEADER.size, "the file header")
        magic, version, checksum = _FILE_HEADER.unpack(head)
        if magic != MAGIC:
            raise BadBgcode(f"{name}: not binary G-code (no GCDE header)")
        if version != 1:
            raise BadBgcode(
                f"{name}: binary G-code version {version}, printhost reads 1"
            )
        if checksum not in (0, 1):
            raise BadBgcode(f"{name}: unknown checksum type {checksum}")
        self.checksums = checksum == 1

    @property
    def offset(self) -> int:
        """Bytes read so far."""
        return self._offset

    def blocks(self) -> Iterator[Block]:
        """Every block, its checksum checked, until the end of the file."""
        number = 0
        while True:
            start = self._offset
            first = self._handle.read(1)
            if not first:
                return
            self._offset += 1
            if self._digest is not None:
                self._digest.update(first)
            number += 1
            yield self._block(number, start, first)

    def _read(self, size: int, what: str) -> bytes:
        data = self._handle.read(size)
        if len(data) != size:
            raise BadBgcode(
                f"{self._name}: cut off in {what} at byte {self._offset + len(data)}"
                " (the file is truncated)"
            )
        self._offset += size
        if self._digest is not None:
            self._digest.update(data)
        return data

    def _block(self, number: int, start: int, first: bytes) -> Block:
        where = f"block {number} at byte {start}"
        header = first + self._read(_BLOCK_HEADER.size - 1, f"the header of {where}")
        kind, compression, size = _BLOCK_HEADER.unpack(header)
        stored = size
        if compression:
            more = self._read(4, f"the header of {where}")
            header += more
            (stored,) = _U32.unpack(more)
        try:
            block_type = BlockType(kind)
        except ValueError:
            raise BadBgcode(f"{self._name}: {where} has unknown type {kind}") from None
        if compression > 3:
            raise BadBgcode(
                f"{self._name}: {where} has unknown compression {compression}"
            )
        if max(size, stored) > MAX_BLOCK_BYTES:
            raise BadBgcode(f"{self._name}: {where} claims {max(size, stored)} bytes")
        params = self._read(6 if block_type == BlockType.THUMBNAIL else 2, where)
        raw = self._read(stored, where)
        if self.checksums:
            (crc,) = _U32.unpack(self._read(4, f"the checksum of {where}"))
            if zlib.crc32(raw, zlib.crc32(params, zlib.crc32(header))) != crc:
                raise BadBgcode(f"{self._name}: {where} fails its CRC32 check")
        data = self._unpack(raw, compression, size, where)
        if block_type == BlockType.THUMBNAIL:
            image, width, height = struct.unpack("<HHH", params)
            return Block(
                block_type, start, self._offset, data,
                _THUMBNAIL_FORMATS.get(image, f"format {image}"), width, height,
            )  # fmt: skip
        (encoding,) = struct.unpack("<H", params)
        if block_type == BlockType.GCODE:
            if encoding in (1, 2):
                data = meatpack_decode(data)
            elif encoding != 0:
                raise BadBgcode(
                    f"{self._name}: {where} has unknown encoding {encoding}"
                )
        elif encoding != 0:
            raise BadBgcode(f"{self._name}: {where} has metadata encoding {encoding}")
        self._decoded += len(data)
        if self._decoded > EXPANSION * self._offset + EXPANSION_SLACK:
            raise BadBgcode(
                f"{self._name}: by {where} it decodes to {self._decoded} bytes from "
                f"{self._offset}, more than {EXPANSION} times: not a slicer's file"
            )
        return Block(block_type, start, self._offset, data)

    def _unpack(self, raw: bytes, compression: int, size: int, where: str) -> bytes:
        try:
            if compression == 0:
                data = raw
            elif compression == 1:
                # Never more than the header promised (a deflate bomb stops here).
                data = zlib.decompressobj().decompress(raw, size + 1)
            else:
                window = 11 if compression == 2 else 12
                data = heatshrink2.decompress(raw, window_sz2=window, lookahead_sz2=4)
        except (zlib.error, ValueError, RuntimeError) as error:
            raise BadBgcode(
                f"{self._name}: {where} does not decompress: {error}"
            ) from None
        if len(data) != size:
            raise BadBgcode(
                f"{self._name}: {where} decompresses to {len(data)} bytes, "
                f"its header says {size}"
            )
        return data


def metadata_of(block: Block) -> dict[str, str]:
    """A metadata block's `key=value` lines."""
    out: dict[str, str] = {}
    for line in block.data.decode("utf-8", "replace").splitlines():
        key, sep, value = line.partition("=")
        if sep and key.strip():
            out[key.strip()] = value.strip()
    return out


# -- MeatPack -------------------------------------------------------------------
#
# MeatPack packs the 15 most common G-code characters two to a byte (low nibble
# first); a nibble of 0b1111 says a full byte follows for that character. `0xFF 0xFF`
# then a byte is a command: packing on (251) or off (250, for comment lines kept
# as text), reset (249), "no spaces" on (247: the space code means `E`) or off (246).
# The encoder drops the spaces of G lines; the decoder puts one back before each
# parameter letter, as libbgcode's does, so the printer gets `G1 X10 Y20 E.5`.

_PACKED = b"0123456789. \nGX"
_PACKED_NO_SPACES = b"0123456789.E\nGX"
_G_WORD = re.compile(rb"(?<=[^ \n])([XYZEFIJRSGPWHCA])")


def meatpack_decode(data: bytes) -> bytes:
    """Decode one MeatPack-encoded G-code block to text."""
    out = bytearray()
    table = _PACKED
    packing = False
    signals = 0
    command = False
    full = 0  # full-width characters still to come
    held = -1  # a packed character that follows the next full one
    for byte in data:
        if byte == 0xFF:
            if signals:
                command, signals = True, 0
            else:
                signals = 1
            continue
        if command:
            command = False
            if byte == 251:
                packing = True
            elif byte in (250, 249):
                packing = False
            elif byte == 247:
                table = _PACKED_NO_SPACES
            elif byte == 246:
                table = _PACKED
            continue
        pending = (0xFF, byte) if signals else (byte,)
        signals = 0
        for value in pending:
            if not packing:
                out.append(value)
            elif full:
                out.append(value)
                if held >= 0:
                    out.append(held)
                    held = -1
                full -= 1
            else:
                low, high = value & 15, value >> 4
                if low == 15:
                    full += 1
                    if high == 15:
                        full += 1
                    else:
                        held = table[high]
                else:
                    out.append(table[low])
                    if table[low] != 10:  # a newline ends the pair
                        if high == 15:
                            full += 1
                        else:
                            out.append(table[high])
    return _spaced(bytes(out))


def _spaced(text: bytes) -> bytes:
    """G lines with a space before each parameter letter; empty lines dropped."""
    lines = []
    for line in text.split(b"\n"):
        if not line:
            continue
        if line[:1] == b"G":
            line = b"G" + _G_WORD.sub(rb" \1", line[1:])
        lines.append(line)
    if not lines:
        return b""
    return b"\n".join(lines) + b"\n"
