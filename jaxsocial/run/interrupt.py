"""Ctrl-C while XLA works: `in_worker` runs a long call into XLA (compiling a program, running a chunk) in a
worker thread, so that a Ctrl-C stops the run at once.

CPython's SIGINT handler only sets a flag; the main thread raises KeyboardInterrupt when it next runs Python
bytecode. A call into XLA's C++ (compiling: tens of seconds, minutes for the paper's program) runs no
bytecode until it returns, so a Ctrl-C waited for the whole compile. XLA releases the GIL while it works, so
the call can run in another thread while the main thread waits on a lock, which a signal does interrupt:
`in_worker` then raises `Interrupted` in the main thread at once, naming what was interrupted. The worker
cannot be stopped: it is a daemon thread, and a process that ends while it still works ends with
`os._exit(EXIT_STATUS)` once the exception has unwound (its `finally` blocks ran: locks released, files
closed), rather than wait for XLA or tear the interpreter down under it.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import sys
import threading
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")
EXIT_STATUS = 130
"""The exit status of a process interrupted by Ctrl-C (128 + SIGINT), as a shell reports it."""

WAKE_S = 0.25
"""How often the waiting thread wakes, to handle a signal the kernel gave another thread (whose own wait it
interrupted instead)."""

_ABANDONED: list[threading.Event] = []
"""The ends of the workers an interrupt left behind: set once a worker has returned."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C while a worker of `in_worker` ran (`what`: e.g. 'compiling the 10-iteration chunk')."""

    def __init__(self, what: str):
        super().__init__(what)
        self.what = what


def in_worker(what: str, fn: Callable[..., T], *args: Any) -> T:
    """`fn(*args)` run in a daemon thread while this thread waits, interruptibly: its result, or its
    exception re-raised here; `Interrupted(what)` on Ctrl-C (or any KeyboardInterrupt raised here), the
    worker left running (`abandoned`), and the process then ends with `os._exit` (`_exit_at_once`)."""
    outcome: dict[str, Any] = {}
    done = threading.Event()

    def work() -> None:
        try:
            outcome["result"] = fn(*args)
        except BaseException as err:  # noqa: BLE001 - re-raised in the waiting thread
            outcome["error"] = err
        finally:
            done.set()

    worker = threading.Thread(target=work, name=f"jaxsocial: {what}", daemon=True)
    try:
        worker.start()
        while not done.wait(WAKE_S):  # not `Thread.join`: interrupted, Python 3.11's join marks it ended
            pass
    except KeyboardInterrupt:
        if worker.ident is not None:  # started
            if not _ABANDONED:  # registered last, so called first: before JAX's own exit handlers
                atexit.register(_exit_at_once)
            _ABANDONED.append(done)
        raise Interrupted(what) from None
    if "error" in outcome:
        raise outcome["error"]
    return outcome["result"]


def abandoned() -> bool:
    """Whether a worker an interrupt left behind still runs."""
    return not all(done.is_set() for done in _ABANDONED)


def _exit_at_once() -> None:
    """At exit, while an abandoned worker still runs: flush and `os._exit(EXIT_STATUS)`, skipping the rest of
    the interpreter's shutdown (which ends daemon threads by unwinding them, aborting the process with
    "terminate called ... FATAL: exception not rethrown" while XLA's C++ is on their stack)."""
    if abandoned():
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        os._exit(EXIT_STATUS)
