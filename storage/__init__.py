"""The archive: database schema, transactional run archiving, raw-data store, queries.

The public API below (docs/api.md) is imported on first use; every question the
archive answers is in `storage.queries`.
"""

from calib_core.lazy import lazy_exports

_API = {
    "Archive": "storage.db",
    "open_archive": "storage.db",
    "history": "storage.queries",
    "parameter_history": "storage.queries",
    "units": "storage.queries",
    "fleet": "storage.queries",
    "latest_calibration": "storage.queries",
    "run_summary": "storage.queries",
    "run_samples": "storage.queries",
    "lineage": "storage.queries",
    "export_calibration": "storage.queries",
}
__all__ = list(_API)
__getattr__, __dir__ = lazy_exports(__name__, _API)
