"""`calib` as a user runs it: the virtual environment's entry point, in a child process."""

from __future__ import annotations

import shutil
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path

# The `calib` script beside this interpreter (the venv's), else the one on PATH.
CALIB = shutil.which("calib", path=str(Path(sys.executable).parent)) or "calib"


def run_calib(
    *args: str, env: Mapping[str, str] | None = None, timeout: float = 600.0
) -> subprocess.CompletedProcess:
    """``calib ARGS`` in a child process with the environment `env` (default: this process's),
    stdout and stderr captured as text; `timeout` in seconds."""
    return subprocess.run([CALIB, *args], capture_output=True, text=True, env=env, timeout=timeout)
