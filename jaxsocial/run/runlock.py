"""The run-directory lock: one process at a time trains in, resumes or overwrites a run directory.

The lock of `runs/NAME` is the file `runs/.NAME.lock` beside it (`rundir.lock_name`, so `--overwrite` can
delete the directory while holding it), locked with `fcntl.flock` and holding its holder's pid, host and
start time. The kernel releases a flock when its process ends, however it ends (kill -9 included); a lock
file whose flock is free but that still names a holder was left by a process that did not release it: it is
stale and taken over, with a warning. A clean release deletes the file.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import sys
import time
from pathlib import Path
from typing import Any, TextIO

from jaxsocial.run import rundir

__all__ = ["RunLock", "RunLockedError", "lock_path"]


class RunLockedError(FileExistsError):
    """Another live process holds the run directory's lock."""


def lock_path(run_dir: str | Path) -> Path:
    """The lock file of `run_dir`: `.<name>.lock` in its parent (`rundir.lock_name`)."""
    run_dir = Path(run_dir)
    return run_dir.parent / rundir.lock_name(run_dir.name)


def _holder(file: TextIO) -> dict[str, Any]:
    """The holder in an open lock file ({} if empty or unreadable)."""
    file.seek(0)
    try:
        holder = json.loads(file.read() or "{}")
    except json.JSONDecodeError:
        return {}
    return holder if isinstance(holder, dict) else {}


FLOCK_TRIES = 5
FLOCK_WAIT_S = 0.1
"""How often, and how far apart, a lock held by someone is tried before it counts as held: a look
(`RunLock.check_free`, `RunLock.live_holder`, from another process too) holds it for an instant."""


def _flock(file: TextIO, mode: int) -> None:
    """`fcntl.flock(file, mode)` without blocking, tried `FLOCK_TRIES` times `FLOCK_WAIT_S` apart where it is
    held; BlockingIOError if it stays held."""
    for attempt in range(FLOCK_TRIES):
        try:
            fcntl.flock(file, mode | fcntl.LOCK_NB)
            return
        except BlockingIOError:
            if attempt == FLOCK_TRIES - 1:
                raise
            time.sleep(FLOCK_WAIT_S)


def _describe(holder: dict[str, Any]) -> str:
    started = holder.get("started")
    since = f" since {time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(started))}" if started else ""
    return f"process {holder.get('pid', '?')} on host {holder.get('host', '?')}{since}"


class RunLock:
    """The exclusive lock of one run directory: `acquire()` ... `release()` (or a `with` block)."""

    def __init__(self, run_dir: str | Path):
        self.run_dir = Path(run_dir)
        self.path = lock_path(self.run_dir)
        self._file: TextIO | None = None

    def acquire(self) -> None:
        """Take the lock. RunLockedError naming the holder (pid, host) if a live process holds it; a stale
        lock is taken over with a warning; on a file system without locks, a warning and no lock."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        while True:
            file = open(self.path, "a+")  # noqa: SIM115 - held open until release()
            try:
                _flock(file, fcntl.LOCK_EX)
            except BlockingIOError:
                holder = _holder(file)
                file.close()
                raise self._in_use(holder) from None
            except OSError as err:
                file.close()
                print(f"warning: cannot lock {self.run_dir} ({err.strerror}); nothing stops another process "
                      "from writing it at the same time", file=sys.stderr)  # fmt: skip
                return
            try:
                same = os.stat(self.path).st_ino == os.fstat(file.fileno()).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            file.close()  # its holder released it (and deleted the file) meanwhile: lock the new one
        stale = _holder(file)
        if stale:
            print(f"warning: taking over the lock of {self.run_dir} left by {_describe(stale)}, which ended "
                  "without releasing it (killed?)", file=sys.stderr)  # fmt: skip
        file.seek(0)
        file.truncate()
        holder = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.time(), "argv": sys.argv}
        file.write(json.dumps(holder) + "\n")
        file.flush()
        self._file = file

    def check_free(self) -> None:
        """RunLockedError naming the holder if a live process holds the lock now; takes nothing, writes
        nothing (a look before the run's checks: `acquire` decides)."""
        try:
            file = open(self.path)  # noqa: SIM115 - closed below
        except OSError:
            return  # no lock file: free
        with file:
            try:
                _flock(file, fcntl.LOCK_EX)
            except BlockingIOError:
                raise self._in_use(_holder(file)) from None
            except OSError:
                return  # a file system without locks: `acquire` warns
            fcntl.flock(file, fcntl.LOCK_UN)

    def live_holder(self) -> dict[str, Any] | None:
        """The holder the lock file names where a live process holds its flock now, else None (no lock file,
        one left by a process that ended however it ended, or a file system without locks). It looks with a
        shared flock released at once, as `check_free` does; `acquire` tries again for a moment where a look
        holds it."""
        try:
            file = open(self.path)  # noqa: SIM115 - closed below
        except OSError:
            return None
        with file:
            try:
                _flock(file, fcntl.LOCK_SH)
            except BlockingIOError:
                return _holder(file)
            except OSError:
                return None
            fcntl.flock(file, fcntl.LOCK_UN)
            return None

    def _in_use(self, holder: dict[str, Any]) -> RunLockedError:
        return RunLockedError(
            f"run directory {self.run_dir} is in use by {_describe(holder)}; wait for that run to end (or "
            f"stop it), or choose another --run-name (lock file {self.path})"
        )

    def release(self) -> None:
        """Delete the lock file and unlock (nothing if not held)."""
        if self._file is None:
            return
        try:
            if os.stat(self.path).st_ino == os.fstat(self._file.fileno()).st_ino:
                self.path.unlink()
        except FileNotFoundError:
            pass
        finally:
            self._file.close()
            self._file = None

    def __enter__(self) -> RunLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
