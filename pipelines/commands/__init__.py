"""Further `calib` commands, one module per area (report, query, thermal, ...).

Every module in this package is imported by `pipelines.cli` (`register_all`) and
registers its commands on the shared app (`pipelines.cli_shared.app`) with
``@app.command()``; none imports `pipelines.cli`.
"""

import importlib
import pkgutil


def register_all() -> None:
    for info in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{info.name}")
