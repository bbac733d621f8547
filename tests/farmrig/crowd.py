"""The farm's clients in processes of their own: `Crowd` runs the websocket watchers
(split over a few processes) and the API load (one more) at nice 10, and brings
what each saw back into the harness's `Watcher` and `ApiLoad` objects.

Why processes: in one asyncio loop on one thread, 100 watchers parsing every line
of 32 printers' logs kept the load's loop so busy that its requests left up to
minutes late, and the clients' latency measured the harness. A process per share
of the watchers and one for the load each keep their own schedule, and nice 10 (on
each process) keeps them off the printers' CPU, as browsers on other computers
would be.

The children are started with `spawn` (the harness has threads and database
connections that a fork would copy). Each talks to the harness over one pipe:

    harness -> child   ("finals", {slug: line})   watchers end once they hold it
                       ("stop",)                  end now (the load: stop sending)
    child -> harness   ("start", index, id)       a watcher's first hello
                       ("watcher", index, state)  at the end: lines, start, reconnects
                       ("load", state)            at the end: the load's figures
                       ("done", [errors])         nothing more will come

What a child holds comes back once, when it ends: the harness never unpickles
lines while the farm is being measured.
"""

from __future__ import annotations

import asyncio
import contextlib
import multiprocessing
import os
import time
import traceback
from multiprocessing.connection import wait
from typing import TYPE_CHECKING, Any

from tests.farmrig.clients import ApiLoad, Watcher

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from multiprocessing.connection import Connection
    from multiprocessing.context import SpawnContext, SpawnProcess

#: The clients' processes run this much nicer than the farm's processes.
CLIENT_NICE = 10
#: Processes the watchers are split over (the load has one more of its own).
WATCHER_PROCESSES = 2
#: Seconds a child may take to start (a fresh interpreter importing httpx and
#: websockets on a busy machine), and to hand its results over once stopped.
START_SECONDS = 60.0
STOP_SECONDS = 60.0


class CrowdFailed(RuntimeError):
    """A client process failed: its figures are missing or incomplete."""


class Crowd:
    """Watchers (and an API load) running in child processes until `finish`/`stop`.

    The `Watcher` and `ApiLoad` objects given stay the harness's: each watcher's
    `start` arrives as it connects, its lines and reconnects (and the load's
    figures) when its process ends.
    """

    def __init__(
        self,
        watchers: list[Watcher],
        key: str,
        load: ApiLoad | None = None,
        *,
        processes: int = WATCHER_PROCESSES,
    ) -> None:
        self.watchers = watchers
        self.key = key
        self.load = load
        #: What went wrong in the children (tracebacks), if anything.
        self.errors: list[str] = []
        count = max(1, min(processes, len(watchers)))
        #: Watcher indexes of each watcher process (every *count*-th watcher, so
        #: each process follows a share of every printer's watchers).
        self._shares = [list(range(n, len(watchers), count)) for n in range(count)]
        self._children: list[_Child] = []

    # -- the harness's side ----------------------------------------------------

    def start(self) -> None:
        """Start the children; return once each runs its clients (bounded)."""
        context = multiprocessing.get_context("spawn")
        for indexes in self._shares:
            group = [self.watchers[i] for i in indexes]
            self._children.append(
                _Child.spawn(context, _follow, (group, self.key), group)
            )
        if self.load is not None:
            self._children.append(_Child.spawn(context, _send_load, (self.load,)))
        self._read_until(lambda: all(c.ready for c in self._children), START_SECONDS)
        if not all(c.ready for c in self._children):
            self.stop()
            raise CrowdFailed(
                f"the client processes did not start within {START_SECONDS:g} s"
            )

    def connected(self) -> bool:
        """Every watcher has had its first hello (reads what has arrived so far)."""
        self._read_until(lambda: False, 0)
        return all(w.start is not None for w in self.watchers)

    def stop_load(self) -> None:
        """Stop the API load (its requests in flight end); the watchers go on."""
        for child in self._children:
            if child.watchers is None:
                child.tell(("stop",))

    def finish(self, finals: dict[str, int], timeout: float) -> None:
        """Let each watcher end once it has its printer's line *finals[slug]*; stop
        everything after *timeout* seconds."""
        for watcher in self.watchers:
            watcher.final = finals[watcher.slug]
        for child in self._watching():
            child.tell(("finals", finals))
        self._read_until(lambda: all(c.done for c in self._watching()), timeout)
        self.stop()

    def stop(self) -> None:
        """End every child and take its results (bounded); raise `CrowdFailed` if a
        child failed or did not hand them over. Once stopped, a no-op."""
        if not self._children:
            return
        for child in self._children:
            child.tell(("stop",))
        self._read_until(lambda: all(c.done for c in self._children), STOP_SECONDS)
        for child in self._children:
            child.end()
            if not child.done:
                self.errors.append(
                    f"client process {child.process.pid} gave no results "
                    f"(exit code {child.process.exitcode})"
                )
        self._children = []
        if self.errors:
            raise CrowdFailed("\n".join(self.errors))

    def _watching(self) -> list[_Child]:
        return [c for c in self._children if c.watchers is not None]

    def _read_until(self, until: Callable[[], bool], timeout: float) -> None:
        """Take the children's messages until *until()* holds, every pipe is closed
        or *timeout* seconds have passed (0: only what is there already)."""
        deadline = time.monotonic() + timeout
        while not until():
            pipes = {c.pipe: c for c in self._children if not c.closed}
            if not pipes:
                return
            left = max(0.0, deadline - time.monotonic())
            readable = wait(list(pipes), left)
            if not readable:
                return
            for pipe in readable:
                self._take(pipes[pipe])

    def _take(self, child: _Child) -> None:
        try:
            message = child.pipe.recv()
        except (EOFError, OSError):
            child.closed = True
            return
        mine = child.watchers or []
        match message:
            case ("ready",):
                child.ready = True
            case ("start", index, start):
                mine[index].start = start
            case ("watcher", index, state):
                mine[index].lines, mine[index].start, mine[index].reconnects = state
            case ("load", state):
                assert self.load is not None
                for name, value in state.items():
                    setattr(self.load, name, value)
            case ("done", errors):
                child.done = True
                self.errors += errors


class _Child:
    """One client process and the harness's end of its pipe."""

    def __init__(
        self, process: SpawnProcess, pipe: Connection, watchers: list[Watcher] | None
    ) -> None:
        self.process = process
        self.pipe = pipe
        #: The harness's objects of the watchers it runs, in the order it was given
        #: them (None: the API load's process).
        self.watchers = watchers
        self.ready = False
        self.done = False
        self.closed = False

    @classmethod
    def spawn(
        cls,
        context: SpawnContext,
        target: Callable[..., None],
        args: tuple[Any, ...],
        watchers: list[Watcher] | None = None,
    ) -> _Child:
        ours, theirs = context.Pipe()
        process = context.Process(target=target, args=(theirs, *args), daemon=True)
        process.start()
        theirs.close()
        return cls(process, ours, watchers)

    def tell(self, message: tuple[Any, ...]) -> None:
        """Send *message* unless the child is gone (it then has nothing to stop)."""
        if not self.closed:
            with contextlib.suppress(OSError):
                self.pipe.send(message)

    def end(self) -> None:
        """Wait for the process to exit (bounded), then kill it if it has not."""
        self.process.join(STOP_SECONDS)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(STOP_SECONDS)
        self.pipe.close()
        self.closed = True


# -- the children's side ---------------------------------------------------------


def _follow(pipe: Connection, watchers: list[Watcher], key: str) -> None:
    """A watcher process: follow the logs until the finals are held or "stop"."""
    _be_nice()
    failed: list[str] = []
    errors = _errors_of(
        lambda: failed.extend(asyncio.run(_follow_logs(pipe, watchers, key)))
    )
    for index, watcher in enumerate(watchers):
        pipe.send(
            ("watcher", index, (watcher.lines, watcher.start, watcher.reconnects))
        )
    pipe.send(("done", failed + errors))


async def _follow_logs(
    pipe: Connection, watchers: list[Watcher], key: str
) -> list[str]:
    """Run the watchers; what each one that failed raised (the others go on)."""
    stop = asyncio.Event()

    def heard(message: tuple[Any, ...]) -> None:
        if message[0] == "finals":
            for watcher in watchers:
                watcher.final = message[1][watcher.slug]
        else:
            stop.set()

    def started(index: int) -> None:
        pipe.send(("start", index, watchers[index].start))

    with _listening(pipe, heard, stop):
        pipe.send(("ready",))
        results = await asyncio.gather(
            *(w.run(key, stop, lambda i=i: started(i)) for i, w in enumerate(watchers)),
            return_exceptions=True,
        )
    return [
        "".join(traceback.format_exception(result)) + f"(watcher of {watcher.slug})"
        for watcher, result in zip(watchers, results, strict=True)
        if isinstance(result, BaseException)
    ]


def _send_load(pipe: Connection, load: ApiLoad) -> None:
    """The API load's process: send until "stop", then hand the figures over."""
    _be_nice()
    errors = _errors_of(lambda: asyncio.run(_run_load(pipe, load)))
    figures = ("latencies", "errors", "lags", "issued", "sent", "seconds")
    pipe.send(("load", {name: getattr(load, name) for name in figures}))
    pipe.send(("done", errors))


async def _run_load(pipe: Connection, load: ApiLoad) -> None:
    stop = asyncio.Event()
    with _listening(pipe, lambda _message: stop.set(), stop):
        pipe.send(("ready",))
        await load.run(stop)


@contextlib.contextmanager
def _listening(
    pipe: Connection,
    heard: Callable[[tuple[Any, ...]], None],
    stop: asyncio.Event,
) -> Iterator[None]:
    """Hand each message of the harness to *heard* from the running loop; a closed
    pipe (the harness gone) sets *stop*."""
    loop = asyncio.get_running_loop()

    def readable() -> None:
        try:
            message = pipe.recv()
        except (EOFError, OSError):
            loop.remove_reader(pipe.fileno())
            stop.set()
            return
        heard(message)

    loop.add_reader(pipe.fileno(), readable)
    try:
        yield
    finally:
        with contextlib.suppress(OSError, ValueError):
            loop.remove_reader(pipe.fileno())


def _errors_of(run: Callable[[], None]) -> list[str]:
    """Run *run*; the traceback of what it raised, if anything."""
    try:
        run()
    except Exception:
        return [traceback.format_exc()]
    return []


def _be_nice() -> None:
    # The clients stand for browsers and hosts on other computers: on this one
    # they must not take the printers' CPU.
    with contextlib.suppress(OSError):
        os.setpriority(os.PRIO_PROCESS, 0, CLIENT_NICE)
