"""The science of IMU calibration: data model, error models, solvers, checks.

Pure numpy/scipy: no files, no database, no Prefect (see docs/architecture.md).
The public API below (docs/api.md) is imported on first use.
"""

from calib_core.lazy import lazy_exports

__version__ = "0.3.0"

_API = {
    "calib_core.recording": ["Recording"],
    "calib_core.calibration": ["Calibration", "Parameter", "CheckResult"],
    "calib_core.thermal": ["ThermalModel"],
    "calib_core.tolerances": ["ToleranceProfile"],
    "calib_core.procedures": ["PROCEDURES", "solve"],
    "calib_core.checks": ["check_calibration", "overall_verdict", "verdict"],
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _API)
__all__ += ["__version__"]
