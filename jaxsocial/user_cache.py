"""Where jaxsocial keeps what it caches for this user between runs: `ROOT`
(``${XDG_CACHE_HOME:-~/.cache}/jaxsocial``), below every module that caches (the compilation cache's `xla/`,
the kernel choices' `autotune.json`)."""

from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(os.environ.get("XDG_CACHE_HOME") or "~/.cache").expanduser() / "jaxsocial"
