"""Clean up after a process however it ends: stop its PostgreSQL servers, remove its folder.

A test run or a benchmark killed by a signal, a timeout or SIGKILL runs no ``finally``
block; its private PostgreSQL server (a daemon in a session of its own) and its temporary
folders would outlive it. :func:`clean_up_after` starts a small process in a new session
(so a signal sent to the run's process group spares it) that waits for the owner to end,
then stops every server whose data directory lies in the folder and removes the folder.
It is also run as a script: ``python watchdog.py <owner pid> <folder>``.
"""

from __future__ import annotations

import contextlib
import os
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

POLL_S = 0.5  # how often the owner's pid is looked at while its pipe stays open
STOP_WAIT_S = 10.0  # an immediate shutdown takes well under this; then SIGKILL


def clean_up_after(folder: Path, owner: int | None = None) -> subprocess.Popen:
    """Start the watchdog of `folder`; it acts when `owner` (default: this process) ends.

    Closing the returned process's stdin releases it early (it then cleans up at once:
    call it after the owner's own cleanup, when there is nothing left to do).
    """
    return subprocess.Popen(
        [sys.executable, str(Path(__file__).resolve()), str(owner or os.getpid()), str(folder)],
        stdin=subprocess.PIPE,
        start_new_session=True,
    )


def release(watchdog: subprocess.Popen) -> None:
    """Let the watchdog finish now (the owner cleaned up itself) and reap it."""
    with contextlib.suppress(OSError):
        watchdog.stdin.close()
    try:
        watchdog.wait(timeout=STOP_WAIT_S + 5)
    except subprocess.TimeoutExpired:
        watchdog.kill()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


# Where a server's pid file lies under a watched folder: `private_server` makes its folder
# (calib-pg-*) in the temporary folder, which is the watched folder itself (a server) or
# its parent (a test run's session folder). Not a walk of the whole tree: a test session's
# folder holds thousands of files.
PID_FILES = ("data/postmaster.pid", "calib-pg-*/data/postmaster.pid")


def stop_servers(folder: Path) -> None:
    """Immediate shutdown (SIGQUIT, then SIGKILL) of every PostgreSQL server of `folder`."""
    for pidfile in (p for pattern in PID_FILES for p in folder.glob(pattern)):
        try:
            pid = int(pidfile.read_text().split()[0])
        except (OSError, ValueError, IndexError):
            continue
        for sig in (signal.SIGQUIT, signal.SIGKILL):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, sig)
            deadline = time.monotonic() + STOP_WAIT_S
            while _alive(pid) and time.monotonic() < deadline:
                time.sleep(0.05)
            if not _alive(pid):
                break


def clean(folder: Path) -> None:
    """Stop the servers of `folder`, then remove it."""
    if folder.exists():
        stop_servers(folder)
        shutil.rmtree(folder, ignore_errors=True)


def _wait_for(owner: int) -> None:
    """Return once `owner` has ended or closed our stdin."""
    while _alive(owner):
        ready, _, _ = select.select([sys.stdin], [], [], POLL_S)
        if ready and not os.read(sys.stdin.fileno(), 4096):
            return


def main(argv: list[str]) -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C aimed at the owner is not for us
    owner, folder = int(argv[1]), Path(argv[2])
    _wait_for(owner)
    clean(folder)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
