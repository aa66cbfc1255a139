"""The example lab's ``lab.toml`` (docs/reports.md) for the tests that issue certificates."""

from __future__ import annotations

from typing import Any

from calib_testing.run_writers import dumps_toml

LABORATORY = {"name": "IMU Lab GmbH", "address": "Musterstrasse 1, 80331 Muenchen, Germany"}
CUSTOMER = {"name": "Example Drones AG", "address": "Hangar 3, 12345 Somewhere"}
CUBE = {"serial": "CUBE-7", "certificate": "DAkkS 4711-2026", "kind": "cube"}


def lab_toml(**tables: Any) -> str:
    """``lab.toml`` text: the example laboratory and customer, `tables` added or replacing
    them (``equipment=[CUBE]`` for the reference cube, ``signing={...}``, ...)."""
    return dumps_toml({"laboratory": LABORATORY, "customer": CUSTOMER, **tables})
