"""Which software produced a number: package version and source revision."""

from __future__ import annotations

import functools
import subprocess
from pathlib import Path

from calib_core import __version__

SOFTWARE_VERSION = __version__


@functools.cache
def source_revision() -> str | None:
    """The git commit of the installed source tree (with '+dirty' when modified), or None."""
    repo = Path(__file__).resolve().parent.parent
    if not (repo / ".git").exists():
        return None

    def git(*args: str) -> str:
        run = subprocess.run(
            ["git", "-C", str(repo), *args], capture_output=True, text=True, timeout=5, check=True
        )
        return run.stdout.strip()

    try:
        rev = git("rev-parse", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return None
    return f"{rev}+dirty" if dirty else rev
