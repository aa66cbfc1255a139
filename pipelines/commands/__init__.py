"""Further `calib` commands, one module per area (report, query, thermal, ...).

Every module in this package is imported by `pipelines.cli` and registers its
commands on `pipelines.cli.app` with ``@app.command()``.
"""

import importlib
import pkgutil


def register_all() -> None:
    for info in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{info.name}")
