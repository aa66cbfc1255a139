#!/usr/bin/env bash
# Make sure a PostgreSQL server (initdb, pg_ctl) is on this machine; the test
# fixtures start their own throw-away server from these binaries.
set -euo pipefail
if ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 || command -v initdb >/dev/null 2>&1; then
    exit 0
fi
if [ "$(id -u)" != 0 ]; then
    echo "PostgreSQL server binaries are missing; install them (apt-get install postgresql) or run as root" >&2
    exit 1
fi
echo "installing PostgreSQL server from Debian's packages..." >&2
export DEBIAN_FRONTEND=noninteractive
apt-get update -q >/dev/null
apt-get install -y -q --no-install-recommends postgresql >/dev/null
