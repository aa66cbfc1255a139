"""Which modules a `calib` command loads: the command run in a fresh interpreter, for the
tests that keep the quick commands free of the science stack."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def modules_loaded(argv: list[str], watch: tuple[str, ...]) -> list[str]:
    """The modules of `watch` a fresh interpreter has loaded after ``calib ARGV`` (which
    must succeed; AssertionError with its output if not)."""
    code = (
        "import json, sys\nfrom pipelines.cli import app\n"
        f"try:\n    app({argv!r})\n"
        "except SystemExit as e:\n    assert not e.code, e.code\n"
        f"print(json.dumps([m for m in {watch!r} if m in sys.modules]))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "80"}
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300
    )
    assert done.returncode == 0, done.stdout + done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])
