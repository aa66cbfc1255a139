"""Prefect's temporary local API server, made to end with the process that started it.

Without a configured PREFECT_API_URL, Prefect starts a local API server (a
uvicorn subprocess) at the first flow run and stops it in an exit hook. A
process that never runs its exit hooks (killed by signal 9, or crashed by
signal 11 in a native library) left that server running, holding the
caller's stdout: ``out=$(calib process ...)`` then waited forever.

:func:`guard_temporary_api` puts a subclass of Prefect's server class in
Prefect's own registry before Prefect makes one, so Prefect starts this one:
the same uvicorn command, run through :func:`main` of this module, which also
watches a pipe whose other end only this process holds. When this process
ends, however it ends, the kernel closes that end; the server sees the end of
the pipe and stops (SIGTERM to itself, uvicorn's clean stop, then exit after
`STOP_GRACE_S`). The server's stdout goes to this process's stderr: stdout
carries data (``calib process --json``).
"""

from __future__ import annotations

import os
import runpy
import signal
import subprocess
import sys
import threading
import time
from typing import Any

STOP_GRACE_S = 5.0  # s for uvicorn's own stop before the server exits anyway


def guard_temporary_api() -> None:
    """Make the temporary API server Prefect starts in this process end with the process.

    Call before the first Prefect API call (a no-op once a server is registered).
    """
    from prefect.server.api.server import SubprocessASGIServer

    class GuardedServer(SubprocessASGIServer):
        _watch_fd: int | None = None

        def _run_uvicorn_command(self) -> subprocess.Popen[Any]:
            self._close_watch()
            read_end, self._watch_fd = os.pipe()
            try:
                return _launch(self.port, read_end)
            finally:
                os.close(read_end)

        def _close_watch(self) -> None:
            if self._watch_fd is not None:
                os.close(self._watch_fd)
                self._watch_fd = None

        def stop(self) -> None:
            super().stop()
            self._close_watch()

    # Prefect keeps its temporary servers by port (None: "any free port") and returns the
    # registered instance from SubprocessASGIServer(), so registering ours first is enough.
    if None not in SubprocessASGIServer._instances:
        GuardedServer()


def _launch(port: int | None, watch_fd: int) -> subprocess.Popen[Any]:
    """Prefect's uvicorn command for its temporary server, run through :func:`main`."""
    import prefect
    from prefect.settings import get_current_settings

    env = {
        **os.environ,
        "PREFECT_UI_ENABLED": "0",
        "PREFECT__SERVER_EPHEMERAL": "1",
        "PREFECT__SERVER_FINAL": "1",
        **get_current_settings().to_environment_variables(exclude_unset=True),
    }
    uvicorn_args = [
        "--app-dir",
        str(prefect.__module_path__.parent),
        "--factory",
        "prefect.server.api.server:create_app",
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
        "--log-level",
        "error",
        "--lifespan",
        "on",
    ]
    return subprocess.Popen(
        [sys.executable, "-m", __name__, str(watch_fd), "uvicorn", *uvicorn_args],
        env=env,
        pass_fds=(watch_fd,),
        stdin=subprocess.DEVNULL,
        stdout=sys.stderr.fileno() if _has_fileno(sys.stderr) else subprocess.DEVNULL,
    )


def _has_fileno(stream: Any) -> bool:
    try:
        stream.fileno()
    except (AttributeError, OSError, ValueError):
        return False
    return True


def _stop_when_closed(fd: int) -> None:
    """Wait for the end of the pipe (the parent is gone), then stop this server."""
    while True:
        try:
            if not os.read(fd, 1):
                break
        except InterruptedError:
            continue
        except OSError:
            break
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(STOP_GRACE_S)
    os._exit(1)


def main(argv: list[str]) -> None:
    """``python -m pipelines.temporary_api FD uvicorn ARGS...``: uvicorn, stopped at FD's end."""
    fd = int(argv[0])
    threading.Thread(target=_stop_when_closed, args=(fd,), daemon=True).start()
    sys.argv = argv[1:]
    runpy.run_module("uvicorn", run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    main(sys.argv[1:])
