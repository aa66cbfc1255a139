"""Glue from lab files to the archive: ingest, Prefect flows, reports, the `calib` CLI.

The public API below (docs/api.md) is imported on first use, so ``import pipelines``
(and `calib --help`) stays fast.
"""

import os

from calib_core.lazy import lazy_exports

# No telemetry: Prefect must not look up its analytics host (see docs/architecture.md).
os.environ.setdefault("DO_NOT_TRACK", "1")
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
# The ephemeral local API server may need longer than Prefect's default to start on a
# busy machine; a timeout there would fail the whole batch.
os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "180")

_API = {
    "pipelines.ingest.run_loader": ["read_run", "discover_runs", "load_run"],
    "pipelines.ingest.errors": ["IngestError"],
    "pipelines.process": ["calibrate", "judge", "process_run"],
    "pipelines.tolerances": ["load_profile"],
    "pipelines.apply": ["apply_calibration"],
    "pipelines.reports.run_reports": ["report_run"],
    "pipelines.run_export": ["export_run"],
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _API)
