"""Host prompts: the firmware's dialog built from action lines, answered with M876."""

from __future__ import annotations

import pytest

from printers.protocol.host_prompts import (
    HostPrompt,
    PromptClosed,
    PromptError,
    PromptShown,
    PromptTracker,
)


def build(tracker: PromptTracker, *lines: str) -> list[object]:
    events = []
    for line in lines:
        action, _, argument = line.removeprefix("//action:").partition(" ")
        event = tracker.on_action(action, argument)
        if event is not None:
            events.append(event)
    return events


M600_PARKED = (
    "//action:prompt_end",
    "//action:prompt_begin Nozzle Parked",
    "//action:prompt_button Continue",
    "//action:prompt_show",
)


def test_a_dialog_is_shown_only_when_the_firmware_says_show():
    tracker = PromptTracker()
    assert build(tracker, *M600_PARKED[:3]) == []
    assert tracker.shown is None
    shown = build(tracker, M600_PARKED[3])
    assert shown == [PromptShown(HostPrompt("Nozzle Parked", ("Continue",)))]


def test_the_answer_is_m876_with_the_button_index_and_closes_the_dialog():
    tracker = PromptTracker()
    build(
        tracker,
        "//action:prompt_begin Filament runout",
        "//action:prompt_choice Purge more",
        "//action:prompt_choice Continue",
        "//action:prompt_show",
    )
    assert tracker.answer(1) == "M876 S1"
    assert tracker.shown is None
    with pytest.raises(PromptError, match="not asking"):
        tracker.answer(0)


@pytest.mark.parametrize("choice", [-1, 2, 9])
def test_an_answer_outside_the_buttons_is_refused_and_the_dialog_stays(choice: int):
    tracker = PromptTracker()
    build(
        tracker,
        "//action:prompt_begin Pick",
        "//action:prompt_button A",
        "//action:prompt_button B",
        "//action:prompt_show",
    )
    with pytest.raises(PromptError, match="not one of the 2"):
        tracker.answer(choice)
    assert tracker.shown == HostPrompt("Pick", ("A", "B"))


def test_a_dialog_without_buttons_takes_choice_zero():
    tracker = PromptTracker()
    build(tracker, "//action:prompt_begin Heating done", "//action:prompt_show")
    assert tracker.answer(0) == "M876 S0"


def test_prompt_end_from_the_firmware_closes_a_shown_dialog():
    tracker = PromptTracker()
    build(tracker, *M600_PARKED)
    assert build(tracker, "//action:prompt_end") == [PromptClosed()]
    assert tracker.shown is None
    assert build(tracker, "//action:prompt_end") == []


def test_a_new_dialog_replaces_the_shown_one():
    tracker = PromptTracker()
    build(tracker, *M600_PARKED)
    events = build(
        tracker,
        "//action:prompt_begin Reheat",
        "//action:prompt_button Reheat",
        "//action:prompt_show",
    )
    assert events == [PromptClosed(), PromptShown(HostPrompt("Reheat", ("Reheat",)))]


def test_buttons_without_a_begin_and_other_actions_change_nothing():
    tracker = PromptTracker()
    assert build(tracker, "//action:prompt_button X", "//action:prompt_show") == []
    assert build(tracker, "//action:pause", "//action:notification Hi") == []
    assert tracker.shown is None
