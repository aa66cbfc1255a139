"""`calib serve` beyond loopback needs a login (pipelines.web.auth).

Truth: the users file written here with the standard KDF (hashlib.scrypt, RFC 7914)
and HTTP's own status codes: a page without a valid login is 401 with a Basic
challenge; with one it is the page. A server on any address but loopback refuses
to start without a users file or a proxy header; loopback stays open.
"""

from __future__ import annotations

import base64
import hashlib
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from test_verify_backup import fill
from typer.testing import CliRunner

from pipelines.cli import app
from pipelines.web.app import create_app
from pipelines.web.auth import add_user, check_password, is_loopback, load_users, require_login
from storage.db import Archive, default_archive_url
from storage.queries import open_readonly

PASSWORD = "correct horse battery"


def _basic(user: str, password: str) -> dict[str, str]:
    return {"Authorization": "Basic " + base64.b64encode(f"{user}:{password}".encode()).decode()}


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> Archive:
    tmp = tmp_path_factory.mktemp("login")
    archive = Archive(default_archive_url(tmp / "store"), tmp / "store")
    archive.upgrade()
    fill(archive, tmp)
    archive.dispose()
    return archive


def test_every_page_needs_a_login_from_the_users_file(small: Archive, tmp_path: Path) -> None:
    users = tmp_path / "users"
    add_user(users, "jane", PASSWORD)
    assert users.stat().st_mode & 0o077 == 0
    ro = open_readonly(small)
    web = create_app(ro)
    require_login(web, load_users(users))
    with TestClient(web) as c:
        for url in ("/runs", "/", "/verify", "/runs/nothing"):
            res = c.get(url, follow_redirects=False)
            assert res.status_code == 401, url
            assert res.headers["www-authenticate"].startswith('Basic realm="calib archive"')
        assert c.get("/runs", headers=_basic("jane", "wrong password")).status_code == 401
        assert c.get("/runs", headers=_basic("mallory", PASSWORD)).status_code == 401
        assert c.get("/runs", headers={"Authorization": "Basic !!!"}).status_code == 401
        res = c.get("/runs", headers=_basic("jane", PASSWORD))
        assert res.status_code == 200 and "0012" in res.text
        assert c.get("/runs", headers=_basic("jane", PASSWORD)).status_code == 200  # cached
    ro.dispose()


def test_behind_a_reverse_proxy_its_header_is_the_login(small: Archive) -> None:
    ro = open_readonly(small)
    web = create_app(ro)
    require_login(web, None, "X-Remote-User")
    with TestClient(web) as c:
        assert c.get("/runs").status_code == 401
        assert c.get("/runs", headers={"X-Remote-User": " "}).status_code == 401
        assert c.get("/runs", headers=_basic("jane", PASSWORD)).status_code == 401  # no file
        assert c.get("/runs", headers={"X-Remote-User": "jane"}).status_code == 200
    ro.dispose()


def test_the_hash_is_standard_scrypt(tmp_path: Path) -> None:
    """A line made with hashlib.scrypt directly checks; one changed byte does not."""
    salt = b"0123456789abcdef"
    key = hashlib.scrypt(PASSWORD.encode(), salt=salt, n=2**14, r=8, p=1, dklen=32)
    stored = f"scrypt$16384$8$1${base64.b64encode(salt).decode()}${base64.b64encode(key).decode()}"
    assert check_password(stored, PASSWORD)
    assert not check_password(stored, PASSWORD + "!")
    (tmp_path / "users").write_text(f"# lab users\njane:{stored}\n")
    assert load_users(tmp_path / "users") == {"jane": stored}
    (tmp_path / "users").write_text("jane:plaintext\n")
    with pytest.raises(ValueError, match="line 1: expected NAME:scrypt"):
        load_users(tmp_path / "users")


@pytest.mark.parametrize(
    ("host", "loopback"),
    [
        ("127.0.0.1", True),
        ("127.0.0.2", True),
        ("::1", True),
        ("localhost", True),
        ("0.0.0.0", False),
        ("::", False),
        ("192.168.1.20", False),
        ("lab-server", False),
    ],
)
def test_loopback_is_told_apart(host: str, loopback: bool) -> None:
    assert is_loopback(host) is loopback


def test_serve_beyond_loopback_refuses_to_start_without_a_login(small: Archive) -> None:
    res = CliRunner().invoke(app, ["serve", "--host", "0.0.0.0", "--archive", str(small.root)])
    assert res.exit_code == 2
    said = " ".join(res.output.split())
    assert "a login is required" in said and "--users FILE" in said, said


def test_serve_user_adds_a_user_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CALIB_SERVE_PASSWORD", PASSWORD)
    users = tmp_path / "users"
    res = CliRunner().invoke(app, ["serve-user", str(users), "jane"])
    assert res.exit_code == 0, res.output
    assert check_password(load_users(users)["jane"], PASSWORD)
    res = CliRunner().invoke(app, ["serve-user", str(users), "jane"])
    assert res.exit_code == 2 and "exists already" in res.output
