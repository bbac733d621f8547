"""The upload check and the protocol agree: what passes the check is sent as checked.

Every line `inspect_file` accepts is one `MarlinProtocol` / `GrblProtocol` takes, so
an accepted file never fails mid-print over a character; what cannot be sent is
refused at upload with its line number. Messages (M117, M118) are sent as ASCII.
"""

from __future__ import annotations

import re

import pytest
from hypothesis import given
from hypothesis import strategies as st

from jobs.gcode import BadGcode, command_of, command_problem, inspect_file
from printers.protocol.errors import CommandRejected
from printers.protocol.grbl import GrblProtocol
from printers.protocol.marlin import MarlinProtocol

LINES = [
    "M117 Grüße".encode(),
    "M117 Grüße".encode("latin-1"),
    "M118 日本語 ok".encode(),
    b"M117 a\x7fb",
    "M0 Weiter? Düse säubern".encode(),
    "G1 X1 ; Düse".encode(),
    "G1 X1 (Kommentar ä)".encode(),
    b"G1\tX1\tY2",
    b"G1 X1\x7f",
    "G1 X1 Ü".encode(),
    b"G1 X\xff",
    "[ESP700]/sd/grüße.gco".encode(),
    b"G1 X1 ?",
    b"M117 Done!",
    b"N10 G1 X1",
    b"n 7 M110 N500",
]


@pytest.mark.parametrize("raw", LINES)
@pytest.mark.parametrize("firmware", ["marlin", "grbl"])
def test_a_line_passes_the_check_exactly_when_the_protocol_takes_it(raw, firmware):
    text = command_of(raw)
    problem = command_problem(text, grbl=firmware == "grbl")
    protocol = MarlinProtocol() if firmware == "marlin" else GrblProtocol()
    if text.startswith("[ESP"):
        return  # the stream host answers these; they never reach the protocol
    try:
        protocol.send(text, 0.0)
        taken = True
    except CommandRejected:
        taken = False
    assert taken == (not problem), (text, problem)


def test_messages_are_sent_as_ascii_and_comments_as_nothing():
    assert command_of("M117 Grüße aus Köln".encode()) == "M117 Grusse aus Koln"
    assert command_of("M117 Grüße".encode("latin-1")) == "M117 Gr??e"
    assert command_of("M118 E1 5 °C 日本".encode()) == "M118 E1 5 degC ??"
    assert command_of("M104 S200 ; Düse".encode()) == "M104 S200"
    assert command_of(b"G1\tX1") == "G1 X1"
    assert command_of(b"M1170 \xc3\xbc") == "M1170 \xfc"  # not a message command


@pytest.mark.parametrize(
    ("content", "line", "what"),
    [
        (b"G28\nG1 X1\x7f\n", 2, "control byte 0x7f"),
        ("G28\nG1 X1\nG1 Y2 Ü\n".encode(), 3, "'Ü' (U+00DC)"),
        (b"G28\nG1 X\xff\n", 2, "not UTF-8"),
    ],
)
def test_the_check_refuses_what_cannot_be_sent_with_its_line(
    tmp_path, content, line, what
):
    path = tmp_path / "bad.gcode"
    path.write_bytes(content)
    with pytest.raises(
        BadGcode, match=rf"bad.gcode line {line}: .*{re.escape(what)}.*cannot be sent"
    ):
        inspect_file(path)


def test_grbl_files_may_not_hold_realtime_characters_in_a_line(tmp_path):
    path = tmp_path / "bad.nc"
    path.write_bytes(b"G21\nG1 X1 F100 ; why? fine in a comment\nM117 Done!\n")
    inspect_file(path)  # Marlin takes it
    with pytest.raises(BadGcode, match=r"line 3: '!' is a GRBL realtime command"):
        inspect_file(path, grbl=True)


@pytest.mark.django_db
def test_printer_scripts_the_protocol_would_refuse_are_refused_with_their_line(
    make_printer, django_user_model, client
):
    from printhost.access import issue_key

    printer = make_printer()
    root = django_user_model.objects.create_superuser("root", "", "pw")
    _, key = issue_key(root, "t")
    response = client.patch(
        f"/printer/config/{printer.slug}",
        {"end_script": "M104 S0 ; Düse aus\nM117 Fertig ✓\n"},
        content_type="application/json",
        HTTP_X_API_KEY=key,
    )
    assert response.status_code == 400, response.content
    assert "end_script: line 2: '✓' (U+2713) cannot be sent" in response.json()["error"]
    printer.refresh_from_db()
    assert printer.end_script == ""
    response = client.patch(
        f"/printer/config/{printer.slug}",
        {"end_script": "M104 S0 ; Düse aus\nM117 Fertig\n"},
        content_type="application/json",
        HTTP_X_API_KEY=key,
    )
    assert response.status_code == 200, response.content


_ANY_CHAR = st.characters(max_codepoint=0x2FF) | st.sampled_from("\ufffd\x7f\t°")


@given(st.text(alphabet=_ANY_CHAR, max_size=40))
def test_a_line_is_refused_exactly_when_it_holds_a_character_outside_printable_ascii(
    text: str,
):
    """The quick test for printable ASCII agrees with the character-by-character one
    on any text: accented letters, control bytes, DEL, the replacement character."""
    outside = any(not " " <= char <= "~" for char in text)
    numbered = re.match(r"[Nn]\s*\d", text) is not None  # a line number of its own
    assert bool(command_problem(text)) == (outside or numbered)
