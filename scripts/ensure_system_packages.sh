#!/usr/bin/env bash
# Make sure a PostgreSQL server (initdb, pg_ctl) is on this machine; the test
# fixtures start their own throw-away server from these binaries. Also poppler's
# pdftoppm, with which the report tests render PDF pages to PNG, and Debian's
# chromium, which the `calib serve` browser tests drive through Playwright
# (Playwright's own browser download is not used). And Pango, with which WeasyPrint
# typesets the impact look-back's PDF (pipelines/impact.py; the certificate needs no
# system library: Typst).
set -euo pipefail
PDF_PACKAGES="libpango-1.0-0 libpangoft2-1.0-0 fonts-dejavu-core"
if { ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 || command -v initdb >/dev/null 2>&1; } \
    && command -v pdftoppm >/dev/null 2>&1 && [ -x /usr/bin/chromium ] \
    && ldconfig -p | grep -q 'libpangoft2-1.0.so.0' && fc-list 2>/dev/null | grep -qi dejavu; then
    exit 0
fi
if [ "$(id -u)" != 0 ]; then
    echo "PostgreSQL server binaries, pdftoppm, chromium or Pango are missing; install them (apt-get install postgresql poppler-utils chromium libpango-1.0-0 libpangoft2-1.0-0) or run as root" >&2
    exit 1
fi
echo "installing PostgreSQL server, poppler-utils, chromium and Pango from Debian's packages..." >&2
export DEBIAN_FRONTEND=noninteractive
apt-get update -q >/dev/null
# shellcheck disable=SC2086
apt-get install -y -q --no-install-recommends postgresql poppler-utils chromium \
    $PDF_PACKAGES >/dev/null
