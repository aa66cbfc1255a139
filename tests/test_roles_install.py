"""The roles installed as docs/postgresql.md says, on a fresh server of their own.

Truth: PostgreSQL itself. The steps are the document's, run with the server's own client
programs (`createuser`, `createdb`; `--pwprompt` needs a terminal and the test server
trusts local connections, so no password is set): the owner `calib`, made by a superuser
as the document says, runs `apply_roles` twice (after the first start and again, as after
an upgrade); both succeed, and the reader and writer are still refused what they must be.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from sqlalchemy.engine import make_url
from test_archive import make_run
from test_roles import _as, _denied

from calib_testing.pgserver import ServerUnavailableError, private_server
from storage.archive import archive_run
from storage.db import Archive
from storage.pgtools import tool
from storage.roles import APPROVER, READER, WRITER, apply_roles
from storage.verify import verify

pytestmark = pytest.mark.postgres


@pytest.fixture(scope="module")
def fresh_server() -> str:
    try:
        with private_server() as url:
            yield url
    except ServerUnavailableError as exc:
        pytest.skip(str(exc))


def _as_superuser(url: str, program: str, *args: str) -> None:
    """`sudo -u postgres PROGRAM ARGS`: the client program as the server's superuser."""
    u = make_url(url)
    cmd = [str(tool(program)), "-h", u.host, "-p", str(u.port), "-U", "postgres", *args]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr


def test_the_documented_installation(fresh_server: str, tmp_path: Path) -> None:
    _as_superuser(fresh_server, "createuser", "calib")  # step 1: the owner
    _as_superuser(fresh_server, "createdb", "-O", "calib", "calib")
    owner_url = make_url(fresh_server).set(username="calib", database="calib")
    owner = Archive(owner_url.render_as_string(hide_password=False), tmp_path / "store")
    owner.upgrade()  # step 2: the first command creates the schema

    with pytest.raises(PermissionError, match="createuser|CREATE ROLE"):
        apply_roles(owner)  # before the administrator's step: the owner may not make roles
    for role in (READER, WRITER, APPROVER):  # step 3, once, by the administrator
        _as_superuser(fresh_server, "createuser", role)
    apply_roles(owner)  # step 3, as the owner
    apply_roles(owner)  # again, as after every upgrade

    url = owner_url.render_as_string(hide_password=False)
    reader, writer = _as(url, READER, owner.root), _as(url, WRITER, owner.root)
    res = archive_run(writer, make_run(tmp_path / "in"))
    assert res.status == "ok"
    _denied(reader, "UPDATE runs SET operator = 'mallory'")
    _denied(reader, "DELETE FROM parameters")
    _denied(writer, "DELETE FROM runs")
    _denied(writer, "UPDATE parameters SET value = 0")
    _denied(writer, "UPDATE audit_events SET actor = 'mallory'")
    _denied(writer, "ALTER ROLE calib_writer SUPERUSER")
    assert verify(owner, orphans=False).ok
    for a in (owner, reader, writer):
        a.dispose()
