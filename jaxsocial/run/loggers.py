"""What a run reports as it trains, beside its metrics file: the terminal progress line (`Progress`) and the
optional external loggers (`make_logger`: TensorBoard, Weights & Biases), each fed the same metrics rows as
`jaxsocial.run.rundir.MetricsLog`.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from collections.abc import Mapping
from datetime import timedelta
from pathlib import Path
from typing import Any, Protocol, TextIO

import numpy as np


def _fmt_value(v: Any) -> str:
    """Floats with 3 significant digits, ints with thousands separators, arrays element-wise."""
    if isinstance(v, np.generic | np.ndarray) or (hasattr(v, "__array__") and not isinstance(v, str)):
        a = np.asarray(v)
        if a.ndim == 0:
            return _fmt_value(a.item())
        return (
            "["
            + ", ".join(_fmt_value(x) for x in a.reshape(-1).tolist()[:8])
            + (", ..." if a.size > 8 else "")
            + "]"
        )
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int):
        return f"{v:,}"
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)


def _fmt_time(seconds: float) -> str:
    return str(timedelta(seconds=int(max(seconds, 0))))


class Progress:
    """Dependency-free progress line, e.g. ``train  40/200 [20%] 12,345 env-steps/s loss=0.123  eta 0:01:10``.

    On a TTY the line is rewritten in place with ``\\r``; otherwise a new line is printed at most every
    `interval` seconds (and at completion), which keeps CI logs short. The rate is (n - initial) * unit_scale
    per second since construction, less the time given to `exclude`, shown in `unit`/s.
    """

    def __init__(
        self,
        total: int,
        desc: str = "",
        *,
        initial: int = 0,
        unit: str = "it",
        unit_scale: float = 1.0,
        interval: float = 5.0,
        stream: TextIO | None = None,
    ):
        self.total, self.desc, self.unit, self.unit_scale = int(total), desc, unit, unit_scale
        self.initial = self.n = int(initial)
        self.interval = interval
        self.stream = stream if stream is not None else sys.stdout
        isatty = getattr(self.stream, "isatty", None)
        self.tty = bool(isatty and isatty())
        self.start = time.monotonic()
        self._last_print = -math.inf
        self._line = ""
        self._printed_line = ""
        self._width = 0
        self.closed = False

    def format(self, n: int, fields: Mapping[str, Any]) -> str:
        """The progress line for `n` completed units and extra `fields`."""
        elapsed = time.monotonic() - self.start
        width = len(str(self.total))
        parts = [self.desc] if self.desc else []
        pct = f" [{100 * n / self.total:3.0f}%]" if self.total > 0 else ""
        parts.append(f"{n:>{width}}/{self.total}{pct}")
        advanced = n - self.initial
        rate = advanced / elapsed if elapsed > 0 and advanced > 0 else None
        if rate is not None:
            scaled = rate * self.unit_scale
            parts.append(f"{scaled:,.0f} {self.unit}/s" if scaled >= 100 else f"{scaled:.3g} {self.unit}/s")
        parts += [f"{k}={_fmt_value(v)}" for k, v in fields.items()]
        if n >= self.total:
            tail = f"elapsed {_fmt_time(elapsed)}"
        else:
            tail = f"eta {_fmt_time((self.total - n) / rate)}" if rate else "eta ?"
        return " ".join(parts) + "  " + tail

    def exclude(self, seconds: float) -> None:
        """Leave `seconds` just spent (e.g. compiling) out of the rate and the ETA."""
        self.start += seconds

    def update(self, n: int, **fields: Any) -> None:
        """Shows progress: `n` is the number of completed units so far (absolute, not an increment) and
        `fields` extra name=value pairs (floats: 3 significant digits; ints: thousands separators)."""
        self.n = int(n)
        self._line = self.format(self.n, fields)
        now = time.monotonic()
        if self.tty:
            self._write("\r" + self._line.ljust(self._width))
            self._width = len(self._line)
        elif now - self._last_print >= self.interval or self.n >= self.total:
            self._write(self._line + "\n")
            self._printed_line = self._line
        else:
            return
        self._last_print = now

    def _write(self, text: str) -> None:
        self.stream.write(text)
        self.stream.flush()

    def close(self) -> None:
        """Ends the display (newline on a TTY; the last state if it was not printed yet otherwise)."""
        if self.closed:
            return
        self.closed = True
        if self.tty and self._width:
            self._write("\n")
        elif not self.tty and self._line and self._line != self._printed_line:
            self._write(self._line + "\n")

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ----------------------------------------------------------------------------------------------------------
# Optional external loggers
# ----------------------------------------------------------------------------------------------------------


class Logger(Protocol):
    def log(self, row: Mapping[str, Any], step: int) -> None: ...

    def close(self) -> None: ...


def _scalars(row: Mapping[str, Any]) -> dict[str, float]:
    """Finite numeric scalars of `row` as floats (arrays and strings dropped)."""
    out = {}
    for k, v in row.items():
        try:
            a = np.asarray(v)
        except Exception:
            continue
        if a.ndim == 0 and a.dtype.kind in "biuf" and math.isfinite(float(a)):
            out[k] = float(a)
    return out


class _NullLogger:
    def log(self, row: Mapping[str, Any], step: int) -> None:
        pass

    def close(self) -> None:
        pass


class _TensorBoardLogger:
    def __init__(self, run_dir: Path, config: Mapping[str, Any]):
        try:
            from tensorboardX import SummaryWriter
        except ImportError:
            try:
                from torch.utils.tensorboard import SummaryWriter
            except ImportError:
                raise ImportError(
                    "logger 'tensorboard' needs tensorboardX (pip install tensorboardX) or torch"
                ) from None
        self.writer = SummaryWriter(str(run_dir / "tensorboard"))
        self.writer.add_text("config", "```\n" + json.dumps(config, indent=2, sort_keys=True) + "\n```")

    def log(self, row: Mapping[str, Any], step: int) -> None:
        for k, v in _scalars(row).items():
            self.writer.add_scalar(k, v, step)

    def close(self) -> None:
        self.writer.close()


class _WandbLogger:
    """wandb run; project from $WANDB_PROJECT (default "jaxsocial"), mode from $WANDB_MODE."""

    def __init__(self, run_dir: Path, config: Mapping[str, Any]):
        try:
            import wandb
        except ImportError:
            raise ImportError("logger 'wandb' needs wandb (pip install wandb)") from None
        self.run = wandb.init(
            project=os.environ.get("WANDB_PROJECT", "jaxsocial"),
            name=run_dir.name,
            dir=str(run_dir),
            config=dict(config),
            mode=os.environ.get("WANDB_MODE"),
        )

    def log(self, row: Mapping[str, Any], step: int) -> None:
        self.run.log(_scalars(row), step=step)

    def close(self) -> None:
        self.run.finish()


def make_logger(kind: str | None, run_dir: str | Path, config: Mapping[str, Any]) -> Logger:
    """External logger with `log(row, step)` and `close()`: None/"none" -> no-op, "tensorboard" (tensorboardX
    or torch, logs to run_dir/tensorboard) or "wandb", given the run's `config` as plain JSON values
    (config.json's, `SeedRun.config`). Only finite scalar values are logged. ImportError with the package to
    install if missing."""
    if kind is None or kind == "none":
        return _NullLogger()
    if kind == "tensorboard":
        return _TensorBoardLogger(Path(run_dir), config)
    if kind == "wandb":
        return _WandbLogger(Path(run_dir), config)
    raise ValueError(f"unknown logger {kind!r}; expected None, 'tensorboard' or 'wandb'")
