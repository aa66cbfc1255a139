"""Glue from lab files to the archive: ingest, Prefect flows, reports, the `calib` CLI."""

import os

# No telemetry: Prefect must not look up its analytics host (see docs/architecture.md).
os.environ.setdefault("DO_NOT_TRACK", "1")
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
