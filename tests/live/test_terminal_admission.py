"""The terminal's admission rules (printers/terminal_admission.py), without sockets."""

from __future__ import annotations

from printers.terminal_admission import Admission


def test_clients_that_never_log_in_make_way_for_a_new_one_oldest_first():
    door = Admission(most=2, per_address=2)
    assert door.arrive("p1", "10.0.0.1", "silent-1") is None
    assert door.arrive("p1", "10.0.0.2", "silent-2") is None

    assert door.refusal("p1", "10.0.0.3") == ""
    assert door.arrive("p1", "10.0.0.3", "user") == "silent-1"
    assert door.log_in("p1", "user") == ""
    assert door.log_in("p1", "silent-1") == "too many connections waiting to log in"
    assert door.arrive("p1", "10.0.0.1", "silent-3") is None  # 2 waiting again

    for who, address in (("silent-1", "10.0.0.1"), ("silent-2", "10.0.0.2"),
                         ("silent-3", "10.0.0.1"), ("user", "10.0.0.3")):  # fmt: skip
        door.leave("p1", address, who)
    assert (door.logged_in, door.addresses, door.waiting, door.let_go) == (
        {}, {}, {}, set()
    )  # fmt: skip


def test_logged_in_clients_and_addresses_are_capped():
    door = Admission(most=2, per_address=2)
    for name in ("a", "b"):
        door.arrive("p1", "10.0.0.1", name)
        assert door.log_in("p1", name) == ""
    assert door.refusal("p1", "10.0.0.9") == (
        "too many terminal clients on printer 'p1' (at most 2)"
    )
    assert door.refusal("p2", "10.0.0.1") == (
        "too many terminal connections from 10.0.0.1 (at most 2)"
    )
    assert door.refusal("p2", "10.0.0.9") == ""


def test_a_login_that_finds_the_places_taken_meanwhile_is_refused():
    door = Admission(most=1, per_address=5)
    door.arrive("p1", "10.0.0.1", "first")
    door.arrive("p1", "10.0.0.1", "second")  # lets "first" go: one may wait
    door.arrive("p1", "10.0.0.1", "third")  # lets "second" go
    assert door.log_in("p1", "third") == ""
    door.arrive("p1", "10.0.0.1", "fourth")
    assert door.log_in("p1", "fourth") == (
        "too many terminal clients on printer 'p1' (at most 1)"
    )
    door.leave("p1", "10.0.0.1", "fourth")
    assert door.logged_in == {"p1": 1} and "p1" not in door.waiting
