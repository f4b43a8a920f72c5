"""Ctrl-C stops a training run at once, also while XLA compiles (issue 84): the compile runs in a worker
thread (`jaxsocial.run.interrupt`), the run ends with one line saying what it interrupted and exit status
130, and its directory, which holds no completed iteration, does not block the same command."""

import os
import queue
import signal
import subprocess
import sys
import threading
import time

import pytest
from conftest import TINY_FLAGS

from jaxsocial.run import interrupt

EXIT_WITHIN_S = 10.0
"""How soon after the Ctrl-C the process must have ended (it takes well under a second; the chunk's compile,
which it used to wait for, takes 13 s on 2 busy cores)."""


def test_in_worker_returns_the_result_or_raises_the_error():
    assert interrupt.in_worker("adding", sum, [1, 2, 3]) == 6
    with pytest.raises(ZeroDivisionError):
        interrupt.in_worker("dividing", lambda: 1 / 0)
    assert not interrupt.abandoned()


def _lines(stream, out: queue.Queue) -> None:
    """Each line of `stream` (progress lines end in '\\r'), then None at its end."""
    line = ""
    for char in iter(lambda: stream.read(1), ""):
        if char in "\r\n":
            out.put(line)
            line = ""
        else:
            line += char
    out.put(None)


def _terminal_sigint() -> None:
    """In the child before it starts: SIGINT as a terminal's foreground job has it. A test suite run as a
    background job (`pytest ... &` in a script, as CI may) starts with SIGINT ignored, which its children
    inherit, and Python then installs no KeyboardInterrupt handler: there the run would not see the Ctrl-C
    at all, whatever it does."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_while_compiling_ends_the_run_at_once(tmp_path):
    """Starts the 2-iteration run of TINY's sizes (the environment's scripted experts beside the learner),
    waits for the line that says it compiles its chunk, sends SIGINT 0.2 s later (while XLA compiles
    at its default optimisation: tracing and compiling take seconds), and expects the run over within
    `EXIT_WITHIN_S` with the message and status 130, its lock released."""
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR", "XLA_FLAGS")}
    env["JAX_ENABLE_COMPILATION_CACHE"] = "false"  # compile for real: a cached program loads in a blink
    # and with XLA's default optimisation: the tests' fast-compile flags (conftest) can make the chunk's
    # compile shorter than the wait below, and the run would end before its Ctrl-C
    flags = [f for f in TINY_FLAGS if f != "--no-progress"]  # the compile line is the progress's
    argv = ["-m", "jaxsocial.train", *flags, "--runs-dir", str(tmp_path), "--run-name", "x"]
    proc = subprocess.Popen(
        [sys.executable, "-u", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
        preexec_fn=_terminal_sigint,
    )
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=_lines, args=(proc.stdout, lines), daemon=True).start()
    seen = []
    try:
        while not any("x: compiling the 1-iteration chunk" in line for line in seen):
            line = lines.get(timeout=180)
            assert line is not None, f"the run ended before compiling its chunk: {seen}"
            seen.append(line)
        time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        sent = time.monotonic()
        rc = proc.wait(timeout=120)
        took = time.monotonic() - sent
    finally:
        proc.kill()
    while (line := lines.get(timeout=10)) is not None:
        seen.append(line)
    text = "\n".join(seen)
    assert "interrupted while compiling the 1-iteration chunk" in text, text
    assert "holds no completed iteration, so the same command starts it again" in text, text
    assert "Traceback" not in text
    assert rc == 130, text
    assert took < EXIT_WITHIN_S, f"ended {took:.1f} s after the Ctrl-C"
    assert (tmp_path / "x" / "config.json").is_file()
    assert not (tmp_path / ".x.lock").exists()
