"""What a pytest run covers, by package and by procedure (scripts/fast_tier_coverage.py).

A pytest plugin (``-p calib_testing.tier_coverage``, active with ``--tier-coverage FILE``):
every procedure the run's tests solve through `calib_core.procedures.solve` (the one entry
of every solve: the pipeline's, `solve_step`'s, the tests' own), with the tests that did,
and the project's modules loaded in the test processes. It writes them as JSON to FILE (a
pytest-xdist worker to FILE.<worker id>). Runs in child processes (`calib process`) are not
seen: what the file lists is what the tests reach in their own process.
"""

from __future__ import annotations

import functools
import json
import os
import sys
from collections import defaultdict
from pathlib import Path

import pytest

PACKAGES = ("calib_core", "storage", "pipelines", "calib_testing")

_solved: dict[str, set[str]] = defaultdict(set)
_current: list[str] = [""]


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--tier-coverage",
        metavar="FILE",
        help="write the procedures solved and the project modules loaded to FILE (JSON)",
    )


def pytest_configure(config: pytest.Config) -> None:
    if not config.getoption("--tier-coverage"):
        return
    import calib_core.procedures as procedures

    solve = procedures.solve

    @functools.wraps(solve)
    def recorded(procedure, *args, **kwargs):
        _solved[procedure].add(_current[0])
        return solve(procedure, *args, **kwargs)

    procedures.solve = recorded  # solve_step looks `solve` up in the module at each call


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item):
    _current[0] = item.nodeid
    try:
        return (yield)
    finally:
        _current[0] = ""


def pytest_sessionfinish(session: pytest.Session) -> None:
    out = session.config.getoption("--tier-coverage")
    if not out:
        return
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    path = Path(f"{out}.{worker}" if worker else out)
    modules = sorted(m for m in sys.modules if m.split(".")[0] in PACKAGES)
    doc = {"solved": {k: sorted(v) for k, v in _solved.items()}, "modules": modules}
    path.write_text(json.dumps(doc, indent=1), encoding="utf-8")
