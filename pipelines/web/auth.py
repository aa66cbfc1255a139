"""A login for `calib serve` on a non-loopback address: HTTP Basic against a users file,
or a reverse proxy's header (docs/serve.md).

The users file holds one ``name:hash`` a line (``#`` comments and blank lines
skipped); the hash is scrypt (`hashlib.scrypt`, RFC 7914) written as
``scrypt$<n>$<r>$<p>$<salt base64>$<key base64>``, made by `hash_password` (``calib
serve-user FILE NAME``). A password is checked once per process and then held as its
SHA-256 only, so pages do not pay the KDF's ~50 ms each.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import hmac
import ipaddress
import os
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.responses import HTMLResponse, Response

SCRYPT_N, SCRYPT_R, SCRYPT_P = 2**14, 8, 1  # RFC 7914's interactive-login parameters
_MAXMEM = 64 * 1024 * 1024
REALM = "calib archive"


def hash_password(password: str, *, n: int = SCRYPT_N, r: int = SCRYPT_R, p: int = SCRYPT_P) -> str:
    """The users file's form of `password`: scrypt with a random 16-byte salt."""
    if len(password) < 8:
        raise ValueError("password: at least 8 characters")
    salt = os.urandom(16)
    key = hashlib.scrypt(password.encode(), salt=salt, n=n, r=r, p=p, maxmem=_MAXMEM, dklen=32)
    return f"scrypt${n}${r}${p}${_b64(salt)}${_b64(key)}"


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode()


def check_password(stored: str, password: str) -> bool:
    """Whether `password` gives `stored` (a `hash_password` string)."""
    try:
        kind, n, r, p, salt, key = stored.split("$")
        if kind != "scrypt":
            return False
        want = base64.b64decode(key, validate=True)
        got = hashlib.scrypt(
            password.encode(),
            salt=base64.b64decode(salt, validate=True),
            n=int(n),
            r=int(r),
            p=int(p),
            maxmem=_MAXMEM,
            dklen=len(want),
        )
    except (ValueError, binascii.Error):
        return False
    return hmac.compare_digest(got, want)


def load_users(path: Path) -> dict[str, str]:
    """name -> hash of a users file; ValueError naming file, line and what is wrong."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise ValueError(f"users file {path}: cannot be read ({exc.strerror or exc})") from None
    users: dict[str, str] = {}
    for n, line in enumerate(lines, 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        name, sep, stored = line.strip().partition(":")
        parts = stored.split("$")
        if not sep or not name or len(parts) != 6 or parts[0] != "scrypt":
            raise ValueError(
                f"users file {path}, line {n}: expected NAME:scrypt$N$R$P$SALT$KEY "
                f"(calib serve-user), found {line[:40]!r}"
            )
        if name in users:
            raise ValueError(f"users file {path}, line {n}: user {name!r} is listed twice")
        users[name] = stored
    if not users:
        raise ValueError(f"users file {path}: no user in it (calib serve-user {path} NAME)")
    return users


def add_user(path: Path, name: str, password: str) -> None:
    """Add `name` to the users file (made if missing, mode 600); refused if listed."""
    if not name or ":" in name or any(ord(c) < 33 for c in name):
        raise ValueError(f"user name: no colon, space or control character, got {name!r}")
    path = Path(path)
    users = load_users(path) if path.is_file() and path.stat().st_size else {}
    if name in users:
        raise ValueError(f"users file {path}: user {name!r} exists already")
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
    with os.fdopen(fd, "a", encoding="utf-8") as f:
        f.write(f"{name}:{hash_password(password)}\n")


def is_loopback(host: str) -> bool:
    """Whether `host` (the address `calib serve` binds) is reachable from this machine only."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False  # a name: it may resolve to anything


def require_login(
    app: FastAPI, users: dict[str, str] | None = None, proxy_header: str | None = None
) -> None:
    """Refuse every request without a valid login (401), by `users` (HTTP Basic) or the
    reverse proxy's `proxy_header` naming the user it authenticated."""
    good: set[tuple[str, bytes]] = set()  # (user, SHA-256 of the password) checked once

    def _basic(request: Request) -> str | None:
        scheme, _, value = request.headers.get("authorization", "").partition(" ")
        if scheme.lower() != "basic" or users is None:
            return None
        try:
            name, _, password = base64.b64decode(value, validate=True).decode().partition(":")
        except (ValueError, binascii.Error):
            return None
        token = (name, hashlib.sha256(password.encode()).digest())
        if token in good:
            return name
        if name in users and check_password(users[name], password):
            good.add(token)
            return name
        return None

    @app.middleware("http")
    async def _login(request: Request, call_next):  # noqa: ANN001, ANN202
        user = request.headers.get(proxy_header, "").strip() if proxy_header else ""
        user = user or _basic(request)
        if not user:
            return _refused()
        request.state.user = user
        return await call_next(request)


def _refused() -> Response:
    return HTMLResponse(
        "a login is needed to browse this archive",
        status_code=401,
        headers={
            "WWW-Authenticate": f'Basic realm="{REALM}", charset="UTF-8"',
            "Cache-Control": "no-store",
        },
    )
