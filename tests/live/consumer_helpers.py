"""Helpers of the websocket feeds' tests: an in-memory layer per test, keys with a
role, clients connected and the messages they wait for."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from typing import Any

import pytest
from channels.layers import channel_layers
from channels.testing import WebsocketCommunicator
from django.contrib.auth import get_user_model

from printers.models import Printer
from printhost.access import issue_key
from printhost.asgi import application
from printhost.models import PrinterRole

TIMEOUT = 5


@pytest.fixture(autouse=True)
def fresh_layer() -> Iterator[None]:
    """Each test runs its own event loop: give it its own in-memory layer."""
    channel_layers.backends.clear()
    yield
    channel_layers.backends.clear()


def user_key(
    name: str,
    role: int | None,
    printer: Printer | None = None,
    bound: Printer | None = None,
) -> str:
    user = get_user_model().objects.create_user(name, password=name)
    if role is not None:
        PrinterRole.objects.create(user=user, role=role, printer=printer)
    return issue_key(user, "test", printer=bound)[1]


def run(coroutine: Any) -> Any:
    return asyncio.run(asyncio.wait_for(coroutine, 30))


async def connect(path: str, headers: list | None = None) -> WebsocketCommunicator:
    client = WebsocketCommunicator(application, path, headers=headers or [])
    connected, _ = await client.connect(timeout=TIMEOUT)
    assert connected
    return client


async def until(client: WebsocketCommunicator, kind: str) -> dict:
    while True:
        message = await client.receive_json_from(timeout=TIMEOUT)
        if message["type"] == kind:
            return message


async def closed_with(path: str, headers: list | None = None) -> tuple[dict, int]:
    client = await connect(path, headers)
    error = await client.receive_json_from(timeout=TIMEOUT)
    close = await client.receive_output(timeout=TIMEOUT)
    assert close["type"] == "websocket.close"
    return error, close["code"]


async def line_ids(client: WebsocketCommunicator, upto: int) -> list[int]:
    seen: list[int] = []
    while not seen or seen[-1] < upto:
        message = await until(client, "lines")
        seen += [line["id"] for line in message["lines"]]
    return seen
