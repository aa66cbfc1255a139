"""A private, throw-away PostgreSQL server for the tests and the benchmarks.

Used by the test fixtures (tests/conftest.py) and the benchmarks. The server runs from the
distribution's binaries (``/usr/lib/postgresql/<version>/bin``, found by
`storage.pgtools`) with a fresh data directory in the temporary folder, trust
authentication on 127.0.0.1 and a free port; ``initdb`` refuses to run as root, so as root
it runs as the ``postgres`` user. It is for tests and benchmarks only (``fsync=off``). A
watchdog process (calib_testing.watchdog) stops it and removes its folder when the process
that started it ends, however it ends.
"""

from __future__ import annotations

import contextlib
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

from calib_testing.watchdog import clean, clean_up_after, release
from storage.pgtools import bindir, libpq_dsn

START_TIMEOUT_S = 30


class ServerUnavailableError(RuntimeError):
    """The machine cannot run a private server (binaries or `postgres` user missing)."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def private_server(**settings: str) -> Iterator[str]:
    """Start a private PostgreSQL server; yield the URL of its `postgres` database.

    Parameters
    ----------
    settings : extra server settings (``-c name=value``), e.g.
        ``shared_buffers="256MB"`` for the benchmark.

    Raises
    ------
    ServerUnavailableError when the binaries or the `postgres` user are missing,
    RuntimeError with the server's log when initdb or the start fail.
    """
    bd = bindir()
    if bd is None:
        raise ServerUnavailableError(
            "PostgreSQL server binaries (initdb, pg_ctl) not found: `make test` installs "
            "them (scripts/ensure_system_packages.sh), or apt-get install postgresql"
        )
    as_root = os.geteuid() == 0
    prefix: list[str] = []
    if as_root:
        try:
            pw = pwd.getpwnam("postgres")
        except KeyError as exc:
            raise ServerUnavailableError(
                "running as root but there is no `postgres` user to run the server as"
            ) from exc
        prefix = ["runuser", "-u", "postgres", "--"]
    base = Path(tempfile.mkdtemp(prefix="calib-pg-"))
    base.chmod(0o755)
    watchdog = clean_up_after(base)
    data = base / "data"
    data.mkdir()
    if as_root:
        for p in (base, data):
            os.chown(p, pw.pw_uid, pw.pw_gid)
    port = free_port()

    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [*prefix, *args], capture_output=True, text=True, timeout=START_TIMEOUT_S
        )

    init = run(
        str(bd / "initdb"),
        "-D",
        str(data),
        "-U",
        "postgres",
        "-A",
        "trust",
        "-E",
        "UTF8",
        "--no-sync",
    )
    if init.returncode:
        shutil.rmtree(base, ignore_errors=True)
        release(watchdog)
        raise RuntimeError(f"initdb failed:\n{init.stderr}")
    opts = f"-p {port} -k {base} -c listen_addresses=127.0.0.1 -c fsync=off"
    opts += "".join(f" -c {k}={v}" for k, v in settings.items())
    start = run(
        str(bd / "pg_ctl"),
        "-D",
        str(data),
        "-o",
        opts,
        "-l",
        str(base / "log"),
        "-w",
        "-t",
        str(START_TIMEOUT_S),
        "start",
    )
    if start.returncode:
        log = (base / "log").read_text() if (base / "log").exists() else ""
        clean(base)
        release(watchdog)
        raise RuntimeError(f"PostgreSQL did not start:\n{start.stderr}\n{log}")
    try:
        yield f"postgresql+psycopg://postgres@127.0.0.1:{port}/postgres"
    finally:
        run(str(bd / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop")
        clean(base)
        release(watchdog)


def admin_execute(url: str, sql: str) -> None:
    """Run one trusted statement outside a transaction (CREATE/DROP DATABASE need that)."""
    import psycopg

    with psycopg.connect(libpq_dsn(url), autocommit=True) as conn:
        conn.execute(sql)
