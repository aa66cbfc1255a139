"""The science of IMU calibration: data model, error models, solvers, checks.

Pure numpy/scipy: no files, no database, no Prefect (see docs/architecture.md).
The public API below (docs/api.md) is imported on first use.
"""

from calib_core.lazy import lazy_exports

__version__ = "0.1.0"

_API = {
    "Recording": "calib_core.recording",
    "Calibration": "calib_core.calibration",
    "Parameter": "calib_core.calibration",
    "CheckResult": "calib_core.calibration",
    "ThermalModel": "calib_core.thermal",
    "ToleranceProfile": "calib_core.tolerances",
    "PROCEDURES": "calib_core.procedures",
    "solve": "calib_core.procedures",
    "check_calibration": "calib_core.checks",
    "verdict": "calib_core.checks",
}
__all__ = [*_API, "__version__"]
__getattr__, __dir__ = lazy_exports(__name__, _API)
