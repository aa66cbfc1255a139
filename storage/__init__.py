"""The archive: database schema, transactional run archiving, raw-data store, queries.

The public API below (docs/api.md) is imported on first use; every question the
archive answers is in `storage.queries`.
"""

from calib_core.lazy import lazy_exports

_API = {
    "storage.db": ["Archive", "open_archive"],
    "storage.queries": [
        "history", "parameter_history", "units", "fleet", "latest_calibration",
        "run_summary", "run_samples", "lineage", "export_calibration",
    ],
}  # fmt: skip
__getattr__, __dir__, __all__ = lazy_exports(__name__, _API)
