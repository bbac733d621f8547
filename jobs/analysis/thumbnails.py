"""Pictures slicers embed in G-code comments, read as the file streams by.

    ; thumbnail begin 300x300 12345        (PNG; also thumbnail_JPG and thumbnail_QOI)
    ; iVBORw0KGgoAAAANSUhEUgAA...          base64, one comment line at a time
    ; thumbnail end

Every size is kept. QOI (PrusaSlicer's compact format for Prusa printers) is turned
into PNG here, so browsers can show every thumbnail. A picture whose base64 or
image data is broken is dropped with a note saying why; the file still prints.
"""

from __future__ import annotations

import base64
import binascii
import re
import struct
import zlib
from dataclasses import dataclass

_BEGIN = re.compile(
    r"^\s*thumbnail(?:_(PNG|JPG|QOI))?\s+begin\s+(\d+)\s*x\s*(\d+)", re.I
)
_END = re.compile(r"^\s*thumbnail(?:_(?:PNG|JPG|QOI))?\s+end\b", re.I)
#: The most base64 one file may carry in thumbnails (a large PNG is ~100 KB); a QOI
#: picture counts its pixels decoded, as it is turned into PNG here.
MAX_BYTES = 8 * 1024 * 1024
#: Pictures kept per file (slicers write one to four); a note each at most: every
#: job of the file carries them.
MAX_PICTURES = 16
MAX_NOTES = 20
_MAX_SIDE = 2048
_PNG = b"\x89PNG\r\n\x1a\n"


class BadPicture(ValueError):
    """The picture's data is not the image it claims to be."""


@dataclass(frozen=True, slots=True)
class Thumbnail:
    width: int
    height: int
    #: "png" or "jpg" (QOI is converted to PNG).
    format: str
    data: bytes


class ThumbnailReader:
    """Collects thumbnails from comments; `comment` says whether it took the line."""

    def __init__(self) -> None:
        self.pictures: list[Thumbnail] = []
        self.notes: list[str] = []
        self._kind = ""
        self._size = (0, 0)
        self._parts: list[str] = []
        self._length = 0
        self._total = 0

    @property
    def reading(self) -> bool:
        """Inside a picture: every comment is part of it."""
        return bool(self._kind)

    def comment(self, text: str) -> bool:
        if self._kind:
            if _END.match(text):
                self._finish()
            else:
                part = text.strip()
                self._length += len(part)
                self._total += len(part)
                if self._total > MAX_BYTES:
                    self._note("thumbnails larger than 8 MB in all were skipped")
                    self._kind, self._parts = "", []
                else:
                    self._parts.append(part)
            return True
        match = _BEGIN.match(text)
        if match is None:
            return False
        self._kind = (match.group(1) or "PNG").upper()
        self._size = (int(match.group(2)), int(match.group(3)))
        self._parts, self._length = [], 0
        return True

    def finish(self) -> None:
        """End of file: a picture still open was cut off."""
        if self._kind:
            self._note(f"a {self._size[0]}x{self._size[1]} thumbnail has no end")
            self._kind, self._parts = "", []

    def _finish(self) -> None:
        kind, (width, height), text = self._kind, self._size, "".join(self._parts)
        self._kind, self._parts = "", []
        label = f"{width}x{height} {kind} thumbnail"
        try:
            raw = base64.b64decode(text, validate=True)
        except (binascii.Error, ValueError):
            self._note(f"the {label} has broken base64 and was skipped")
            return
        self._take(kind, raw, label)

    def add(self, kind: str, raw: bytes) -> None:
        """A picture from outside the comments (*kind* PNG, JPG or QOI), checked."""
        self._total += len(raw)
        if self._total > MAX_BYTES:
            self._note("thumbnails larger than 8 MB in all were skipped")
            return
        self._take(kind, raw, f"{kind} thumbnail")

    def _note(self, text: str) -> None:
        if text not in self.notes and len(self.notes) < MAX_NOTES:
            self.notes.append(text)

    def _take(self, kind: str, raw: bytes, label: str) -> None:
        if len(self.pictures) >= MAX_PICTURES:
            self._note(f"more than {MAX_PICTURES} thumbnails: the rest were skipped")
            return
        if kind == "QOI" and len(raw) >= 12:
            width, height = struct.unpack(">II", raw[4:12])
            self._total += width * height * 4
            if self._total > MAX_BYTES:
                self._note("thumbnails larger than 8 MB in all were skipped")
                return
        try:
            self.pictures.append(picture(kind, raw))
        except BadPicture as error:
            self._note(f"the {label} was skipped: {error}")


def picture(kind: str, raw: bytes) -> Thumbnail:
    """A checked thumbnail from decoded bytes of the slicer's *kind* (PNG, JPG, QOI)."""
    if kind == "QOI":
        width, height, pixels = qoi_decode(raw)
        return Thumbnail(width, height, "png", png_encode(width, height, pixels))
    if kind == "JPG":
        if not raw.startswith(b"\xff\xd8") or len(raw) < 4:
            raise BadPicture("not JPEG data")
        width, height = _jpeg_size(raw)
        return Thumbnail(width, height, "jpg", raw)
    if not raw.startswith(_PNG) or raw[12:16] != b"IHDR" or len(raw) < 33:
        raise BadPicture("not PNG data")
    width, height = struct.unpack(">II", raw[16:24])
    return Thumbnail(width, height, "png", raw)


def _jpeg_size(raw: bytes) -> tuple[int, int]:
    at = 2
    while at + 9 < len(raw):
        if raw[at] != 0xFF:
            raise BadPicture("broken JPEG markers")
        marker = raw[at + 1]
        length = struct.unpack(">H", raw[at + 2 : at + 4])[0]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            height, width = struct.unpack(">HH", raw[at + 5 : at + 9])
            return width, height
        at += 2 + length
    raise BadPicture("JPEG without a frame header")


def qoi_decode(raw: bytes) -> tuple[int, int, bytes]:
    """Decode a QOI image (the format's published specification) into RGBA bytes."""
    if len(raw) < 22 or raw[:4] != b"qoif":
        raise BadPicture("not QOI data")
    width, height, _channels, _space = struct.unpack(">IIBB", raw[4:14])
    if not (0 < width <= _MAX_SIDE and 0 < height <= _MAX_SIDE):
        raise BadPicture(f"QOI size {width}x{height} is out of range")
    count = width * height
    out = bytearray(count * 4)
    seen = [(0, 0, 0, 0)] * 64
    r, g, b, a = 0, 0, 0, 255
    at, end, pixel, run = 14, len(raw) - 8, 0, 0
    while pixel < count:
        if run:
            run -= 1
        elif at < end:
            byte = raw[at]
            at += 1
            if byte == 0xFE:
                r, g, b = raw[at], raw[at + 1], raw[at + 2]
                at += 3
            elif byte == 0xFF:
                r, g, b, a = raw[at], raw[at + 1], raw[at + 2], raw[at + 3]
                at += 4
            elif byte >> 6 == 0:
                r, g, b, a = seen[byte]
            elif byte >> 6 == 1:
                r = (r + ((byte >> 4) & 3) - 2) & 255
                g = (g + ((byte >> 2) & 3) - 2) & 255
                b = (b + (byte & 3) - 2) & 255
            elif byte >> 6 == 2:
                second = raw[at]
                at += 1
                dg = (byte & 63) - 32
                r = (r + dg - 8 + ((second >> 4) & 15)) & 255
                g = (g + dg) & 255
                b = (b + dg - 8 + (second & 15)) & 255
            else:
                run = byte & 63
            seen[(r * 3 + g * 5 + b * 7 + a * 11) % 64] = (r, g, b, a)
        else:
            raise BadPicture("QOI data ends before its last pixel")
        out[pixel * 4 : pixel * 4 + 4] = bytes((r, g, b, a))
        pixel += 1
    return width, height, bytes(out)


def png_encode(width: int, height: int, rgba: bytes) -> bytes:
    """A plain RGBA PNG (no filter) of *rgba* pixels."""
    stride = width * 4
    rows = b"".join(
        b"\x00" + rgba[row * stride : (row + 1) * stride] for row in range(height)
    )

    def chunk(tag: bytes, body: bytes) -> bytes:
        crc = zlib.crc32(tag + body) & 0xFFFFFFFF
        return struct.pack(">I", len(body)) + tag + body + struct.pack(">I", crc)

    header = struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)
    return (
        _PNG
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(rows, 6))
        + chunk(b"IEND", b"")
    )
