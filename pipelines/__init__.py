"""Glue from lab files to the archive: ingest, Prefect flows, reports, the `calib` CLI."""

import os

# No telemetry: Prefect must not look up its analytics host (see docs/architecture.md).
os.environ.setdefault("DO_NOT_TRACK", "1")
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
# The ephemeral local API server may need longer than Prefect's 20 s default to start on a
# busy 2-core machine; a timeout there would fail the whole batch.
os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "180")
