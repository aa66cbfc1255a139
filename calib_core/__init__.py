"""The science of IMU calibration: data model, error models, solvers, checks.

Pure numpy/scipy: no files, no database, no Prefect (see docs/architecture.md).
"""

__version__ = "0.1.0"
