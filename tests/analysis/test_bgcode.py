"""Prusa binary G-code: read block by block, checked, and the same job as its text.

The binary files are made from the committed PrusaSlicer slice by libbgcode's own
converter (tests/slices.py), so the reader is checked against the format's
reference writer and reader.
"""

from __future__ import annotations

import base64
import struct
import zlib
from pathlib import Path
from typing import TYPE_CHECKING

import pybgcode
import pytest

from jobs import analysis_task
from jobs.analysis.thumbnails import png_encode
from jobs.bgcode import BadBgcode, BgcodeReader, BlockType, meatpack_decode
from jobs.gcode import BadGcode, command_of, file_lines, inspect_file, iter_commands
from jobs.sdcard import queue_sd_upload
from jobs.services import enqueue_job
from tests.slices import PRUSA, to_binary

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.models import Printer


def thumbnail_comment(width: int, height: int) -> str:
    text = base64.b64encode(
        png_encode(width, height, b"\x20\x90\xe0\xff" * width * height)
    )
    lines = "".join(f"; {text[i : i + 78].decode()}\n" for i in range(0, len(text), 78))
    return f";\n; thumbnail begin {width}x{height} {len(text)}\n{lines}; thumbnail end\n;\n"


@pytest.fixture(scope="module")
def slice_pair(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The PrusaSlicer slice with two thumbnails, as text and as binary G-code."""
    folder = tmp_path_factory.mktemp("bgcode")
    text = PRUSA.read_text()
    first = text.index("\n") + 1
    plain = folder / "box.gcode"
    plain.write_text(
        text[:first]
        + thumbnail_comment(16, 12)
        + thumbnail_comment(32, 24)
        + text[first:]
    )
    return plain, to_binary(plain, folder / "box.bgcode")


def commands(path: Path) -> list[str]:
    return [command.text for command in iter_commands(path)]


def test_the_binary_file_reads_as_the_same_commands_as_its_text(slice_pair) -> None:
    plain, binary = slice_pair
    assert binary.stat().st_size < plain.stat().st_size / 4
    assert commands(binary) == commands(plain)
    assert len(commands(plain)) == 9027


def test_the_decoder_agrees_with_libbgcodes_own(slice_pair, tmp_path: Path) -> None:
    _, binary = slice_pair
    source = pybgcode.open(str(binary), "rb")
    target = pybgcode.open(str(tmp_path / "back.gcode"), "w")
    try:
        assert pybgcode.from_binary_to_ascii(source, target, True) == (
            pybgcode.EResult.Success
        )
    finally:
        pybgcode.close(source)
        pybgcode.close(target)
    theirs = (tmp_path / "back.gcode").read_bytes()
    ours = b"".join(raw for raw, _ in file_lines(binary))
    # libbgcode writes the metadata blocks as comments around it; the G-code is ours.
    assert len(ours) > 200_000
    assert ours in theirs


def test_blocks_give_metadata_and_thumbnails(slice_pair) -> None:
    _, binary = slice_pair
    with binary.open("rb") as handle:
        blocks = list(BgcodeReader(handle, name="box.bgcode").blocks())
    kinds = [block.type for block in blocks]
    assert kinds[:2] == [BlockType.FILE_METADATA, BlockType.PRINTER_METADATA]
    thumbs = [
        (b.image, b.width, b.height) for b in blocks if b.type == BlockType.THUMBNAIL
    ]
    assert thumbs == [("PNG", 16, 12), ("PNG", 32, 24)]
    assert kinds.count(BlockType.GCODE) >= 4
    assert blocks[-1].end == binary.stat().st_size


def test_offsets_are_in_the_stored_file_and_only_grow(slice_pair) -> None:
    _, binary = slice_pair
    offsets = [command.end_offset for command in iter_commands(binary)]
    assert offsets == sorted(offsets)
    assert offsets[-1] == binary.stat().st_size
    assert offsets[len(offsets) // 2] < binary.stat().st_size * 0.7


def test_upload_checks_the_binary_file_and_measures_the_stored_bytes(
    slice_pair,
) -> None:
    plain, binary = slice_pair
    facts, text_facts = inspect_file(binary), inspect_file(plain)
    assert facts.size_bytes == binary.stat().st_size
    assert facts.line_count == text_facts.line_count
    assert facts.longest == text_facts.longest


def broken(binary: Path, out: Path, change: Callable[[bytearray], None]) -> Path:
    data = bytearray(binary.read_bytes())
    change(data)
    out.write_bytes(bytes(data))
    return out


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.__delitem__(slice(len(d) // 2, None)), "truncated"),
        (lambda d: d.__delitem__(slice(len(d) - 2, None)), "truncated"),
        (lambda d: d.__setitem__(len(d) // 2, d[len(d) // 2] ^ 0x40), "CRC32"),
        (lambda d: d.__setitem__(slice(4, 8), struct.pack("<I", 7)), "version 7"),
    ],
    ids=["cut-in-half", "cut-in-a-checksum", "one-bit-flipped", "future-version"],
)
def test_a_broken_binary_file_is_refused_naming_the_break(
    slice_pair, tmp_path: Path, change, message: str
) -> None:
    bad = broken(slice_pair[1], tmp_path / "bad.bgcode", change)
    with pytest.raises(BadGcode, match=message) as error:
        inspect_file(bad, name="mine.bgcode")
    assert str(error.value).startswith("mine.bgcode: ")


def block(kind: int, params: bytes, data: bytes, compression: int = 0) -> bytes:
    sizes = struct.pack("<I", len(data))
    if compression:
        stored = zlib.compress(data)
        header = struct.pack("<HHI", kind, compression, len(data)) + struct.pack(
            "<I", len(stored)
        )
    else:
        stored, header = data, struct.pack("<HH", kind, 0) + sizes
    crc = zlib.crc32(header + params + stored)
    return header + params + stored + struct.pack("<I", crc)


HEADER = b"GCDE" + struct.pack("<IH", 1, 1)


def test_a_hand_made_file_with_plain_blocks_and_a_line_across_blocks(
    tmp_path: Path,
) -> None:
    path = tmp_path / "hand.bgcode"
    path.write_bytes(
        HEADER
        + block(1, b"\0\0", b"G28\nG1 X1")
        + block(1, b"\0\0", b"0 Y2\nM84", compression=1)
    )
    assert commands(path) == ["G28", "G1 X10 Y2", "M84"]


def test_unknown_block_types_and_oversized_claims_are_refused(tmp_path: Path) -> None:
    odd = tmp_path / "odd.bgcode"
    odd.write_bytes(HEADER + block(9, b"\0\0", b"G28\n"))
    with pytest.raises(BadGcode, match="unknown type 9"):
        inspect_file(odd)
    huge = tmp_path / "huge.bgcode"
    huge.write_bytes(HEADER + struct.pack("<HHI", 1, 0, 1 << 31) + b"\0\0G28\n")
    with pytest.raises(BadGcode, match="claims 2147483648 bytes"):
        inspect_file(huge)


def test_a_deflate_bomb_stops_at_the_size_its_header_promised(tmp_path: Path) -> None:
    bomb = zlib.compress(b"G1 X1\n" * 20_000_000)  # 120 MB of text in 120 KB
    header = struct.pack("<HHII", 1, 1, 1000, len(bomb))
    params = b"\0\0"
    crc = struct.pack("<I", zlib.crc32(header + params + bomb))
    path = tmp_path / "bomb.bgcode"
    path.write_bytes(HEADER + header + params + bomb + crc)
    with pytest.raises(
        BadGcode, match="decompresses to 1001 bytes, its header says 1000"
    ):
        inspect_file(path)


def test_meatpack_full_width_characters_and_signal_bytes() -> None:
    # 0xFF 0xFF 0xFB: packing on, 0xFF 0xFF 0xF7: no spaces (the space code is E).
    start = b"\xff\xff\xfb\xff\xff\xf7"
    # "G1" packed, "Y" full then "5" packed, then "E" (space code) and "\n".
    data = start + bytes([0x1D, 0x5F]) + b"Y" + bytes([0xCB])
    assert meatpack_decode(data) == b"G1 Y5 E\n"
    # Packing off: a comment line goes as text; on again for the next G line.
    data += b"\xff\xff\xfa; note\n\xff\xff\xfb" + bytes([0x0D, 0xCF]) + b"\n"
    assert meatpack_decode(data) == b"G1 Y5 E\n; note\nG0\n"


def test_a_binary_upload_is_analysed_like_its_text(
    slice_pair, make_printer: Callable[..., Printer],
    django_capture_on_commit_callbacks: Callable, monkeypatch: pytest.MonkeyPatch,
) -> None:  # fmt: skip
    monkeypatch.setattr("jobs.tasks.analyse_file.delay", lambda pk: None)
    plain, binary = slice_pair
    printer = make_printer(slug="mk4")
    with django_capture_on_commit_callbacks(execute=True):
        text_job = enqueue_job(printer, plain, name="box.gcode", origin="test")
        binary_job = enqueue_job(printer, binary, name="box.bgcode", origin="test")
    assert binary_job.size_bytes == binary.stat().st_size
    assert binary_job.line_count == text_job.line_count
    assert binary_job.path.read_bytes() == binary.read_bytes()  # stored as binary
    assert analysis_task.run(text_job.analysis_id) == "done"
    assert analysis_task.run(binary_job.analysis_id) == "done"
    text_job.analysis.refresh_from_db()
    binary_job.analysis.refresh_from_db()
    ours, theirs = binary_job.analysis.result, text_job.analysis.result
    for key in ("motion_seconds", "heating_seconds", "commands", "bbox", "timeline"):
        assert ours[key] == theirs[key], key
    without_offsets = [
        [
            {k: v for k, v in layer.items() if k != "offset"}
            for layer in result["layers"]
        ]
        for result in (ours, theirs)
    ]
    assert without_offsets[0] == without_offsets[1]
    assert len(ours["layers"]) == 50
    assert ours["slicer"]["slicer"] == "PrusaSlicer"
    assert ours["slicer"]["estimated_seconds"] == 903
    assert sorted(t["width"] for t in ours["thumbnails"]) == [16, 32]


def test_a_binary_file_broken_on_disk_fails_its_analysis_with_the_reason(
    slice_pair, make_printer: Callable[..., Printer], tmp_path: Path,
    django_capture_on_commit_callbacks: Callable, monkeypatch: pytest.MonkeyPatch,
) -> None:  # fmt: skip
    monkeypatch.setattr("jobs.tasks.analyse_file.delay", lambda pk: None)
    printer = make_printer(slug="mk4")
    copy = tmp_path / "copy.bgcode"
    copy.write_bytes(slice_pair[1].read_bytes())
    with django_capture_on_commit_callbacks(execute=True):
        job = enqueue_job(printer, copy, name="box.bgcode", origin="test")
    data = bytearray(job.path.read_bytes())
    data[-100] ^= 1
    job.path.write_bytes(bytes(data))
    assert analysis_task.run(job.analysis_id) == "failed"
    job.analysis.refresh_from_db()
    assert "fails its CRC32 check" in job.analysis.reason


def test_the_reader_refuses_what_is_not_binary_gcode(tmp_path: Path) -> None:
    path = tmp_path / "text.bgcode"
    path.write_bytes(b"G28\nG1 X10\n")
    with path.open("rb") as handle, pytest.raises(BadBgcode, match="no GCDE header"):
        BgcodeReader(handle, name="text.bgcode")
    assert commands(path) == ["G28", "G1 X10"]  # a text file, whatever its name
    assert command_of(b"G1 X1 ; c\n") == "G1 X1"


def test_a_copy_to_the_sd_card_is_named_as_plain_gcode(
    slice_pair, make_printer: Callable[..., Printer], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("jobs.tasks.analyse_file.delay", lambda pk: None)
    printer = make_printer(slug="mk4")
    job = enqueue_job(printer, slice_pair[1], name="box.bgcode", origin="test")
    assert queue_sd_upload(printer, job).sd_name == "BOX.GCO"


def test_a_carriage_return_inside_a_line_splits_nothing_as_in_a_text_file(
    tmp_path: Path,
) -> None:
    text = b"G28\nM117 a\rb\nG1 X1\n"
    binary, plain = tmp_path / "cr.bgcode", tmp_path / "cr.gcode"
    binary.write_bytes(HEADER + block(1, b"\0\0", text))
    plain.write_bytes(text)
    assert [raw for raw, _ in file_lines(binary)] == [
        raw for raw, _ in file_lines(plain)
    ]


def test_a_line_without_end_is_refused_before_it_grows_past_4_mb(
    tmp_path: Path,
) -> None:
    """A line that never ends was held whole, and a binary file's was copied again
    with each block: a 512 KB upload took 16 s and 1.6 GB in the request."""
    chunk = b";" + b"A" * (1 << 20)  # no newline: one line across every block
    binary = tmp_path / "endless.bgcode"
    binary.write_bytes(
        HEADER + block(1, b"\0\0", b"G1 X1\n")
        + b"".join(block(1, b"\0\0", chunk, compression=1) for _ in range(8))
    )  # fmt: skip
    text = tmp_path / "endless.gcode"
    text.write_bytes(b"G1 X1\n" + chunk * 8 + b"\nG1 X2\n")
    for path in (binary, text):
        with pytest.raises(BadGcode, match="longer than 4 MB: not G-code"):
            inspect_file(path, name="endless")


def test_a_file_that_decodes_to_far_more_than_a_slicers_would_is_refused(
    tmp_path: Path,
) -> None:
    """Twenty 8 MB blocks of 22 KB each: 160 MB of G-code from 450 KB, which the
    upload check, the analysis and the worker would each read line by line."""
    comment = b";" + b"A" * 1000 + b"\n"
    data = comment * (8_000_000 // len(comment))
    bomb = tmp_path / "bomb.bgcode"
    bomb.write_bytes(
        HEADER + block(1, b"\0\0", b"G1 X1\n")
        + b"".join(block(1, b"\0\0", data, compression=1) for _ in range(20))
    )  # fmt: skip
    with pytest.raises(BadGcode, match="more than 64 times: not a slicer's file"):
        inspect_file(bomb, name="bomb")


def test_the_analysis_beats_between_thumbnail_blocks(
    make_printer, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Pictures are decoded (a QOI one into PNG, in Python) between G-code blocks:
    a file of many large ones kept the analysis from its heartbeat for minutes,
    and another worker took it over again and again."""
    beats: list[int] = []
    monkeypatch.setattr(analysis_task, "HEARTBEAT_SECONDS", 0.0)
    monkeypatch.setattr(
        analysis_task, "_heartbeat", lambda pk, worker, done: beats.append(done)
    )
    picture = png_encode(4, 4, b"\x80" * 64)
    path = tmp_path / "pictures.bgcode"
    path.write_bytes(
        HEADER
        + b"".join(block(5, struct.pack("<HHH", 0, 4, 4), picture) for _ in range(5))
        + block(1, b"\0\0", b"G28\nG1 X10 E1\n")
    )
    job = enqueue_job(make_printer(), path, name="pictures.bgcode")
    assert analysis_task.run(job.analysis_id) == "done"
    assert len(beats) >= 6, "no heartbeat while the thumbnails were read"
