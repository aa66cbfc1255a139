"""Read-only commands load only what they use (the latency of `calib history`:
benchmarks/latency.py).

The MPU-6000 sample of data_samples/ is processed into a real SQLite archive; each
command runs in a fresh interpreter, which then names the modules it loaded.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from calib_testing.cli_imports import modules_loaded
from pipelines.cli import app
from storage.instants import UTCDateTime
from storage.queries import unit_history
from storage.schema import Base

ROOT = Path(__file__).resolve().parent.parent
SCIENCE = ("numpy", "scipy", "pandas", "pyarrow", "matplotlib", "prefect", "weasyprint", "typst")
# What `calib history` also leaves alone on SQLite: the mapped tables (and the PostgreSQL
# dialect their index options load), PostgreSQL's driver, typer's pydantic conversion.
ARCHIVE_EXTRAS = ("storage.schema", "sqlalchemy.dialects.postgresql", "psycopg", "pydantic")


def test_history_loads_neither_the_science_stack_nor_the_mapped_tables(archived_sample) -> None:
    arch, _ = archived_sample
    argv = ["history", "MPU0001", "--archive", str(arch.root)]
    assert modules_loaded(argv, SCIENCE + ARCHIVE_EXTRAS) == []


@pytest.mark.parametrize(
    "args",
    [["--version"], ["--help"], ["audit", "MPU0001"], ["verify"], ["show", "RUN"]],
    ids=["version", "help", "audit", "verify", "show"],
)
def test_read_only_commands_load_no_science_stack(archived_sample, args) -> None:
    """`calib show` converts values to display units with numpy (calib_core.units), so
    numpy is its one; the others load none of it."""
    arch, run_id = archived_sample
    argv = [run_id if a == "RUN" else a for a in args]
    if not args[0].startswith("--"):
        argv += ["--archive", str(arch.root)]
    allowed = ("numpy",) if args[0] == "show" else ()
    watch = tuple(m for m in SCIENCE if m not in allowed) + ("psycopg",)
    assert modules_loaded(argv, watch) == []


@pytest.mark.parametrize(
    "args",
    [pytest.param(["query", "latest", "MPU0001"], marks=pytest.mark.slow), ["query", "units"]],
    ids=["latest", "units"],
)
def test_queries_load_no_flow_plot_or_typesetting(archived_sample, args) -> None:
    """The questions answer in DataFrames (pandas): no Prefect, plotting or typesetter."""
    arch, _ = archived_sample
    watch = ("matplotlib", "prefect", "weasyprint", "psycopg")
    assert modules_loaded([*args, "--archive", str(arch.root)], watch) == []


@pytest.mark.slow  # builds the serve sample; fast: the commands above in fresh interpreters
def test_trend_table_loads_no_plotting(serve_sample) -> None:
    """A trend fits (numpy, scipy); its table without --plot draws nothing (matplotlib)."""
    argv = ["trend", "DRIFT-01", "acc.bias.x", "--archive", str(serve_sample.archive.root)]
    assert modules_loaded(argv, ("matplotlib", "prefect", "weasyprint", "psycopg")) == []


def test_light_tables_name_the_schema_columns_and_types() -> None:
    """unit_history reads storage.schema's tables by name: every column it names exists
    there, and the instants are typed alike (UTC-aware)."""
    light = (unit_history.DEVICES, unit_history.RUNS, unit_history.CALIBRATIONS)
    for clause in light:
        mapped = Base.metadata.tables[clause.name]
        for col in clause.c:
            assert col.name in mapped.c, f"{clause.name}.{col.name} is not in storage.schema"
            instant = isinstance(mapped.c[col.name].type, UTCDateTime)
            assert isinstance(col.type, UTCDateTime) == instant, f"{clause.name}.{col.name}"


def test_a_question_keeps_its_name_beside_its_module() -> None:
    """`queries.history` is the question after its namesake module is imported."""
    code = (
        "import storage.queries.history\nfrom storage import queries\n"
        "assert callable(queries.history), queries.history\n"
        "assert queries.history.__module__ == 'storage.queries.unit_history'\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    subprocess.run([sys.executable, "-c", code], check=True, env=env, timeout=120)


def test_values_still_converted_and_refused_by_typer(archived_sample) -> None:
    """Values without pydantic where they already have their type; the others (a choice,
    a number) converted, and refused, by typer as before."""
    arch, _ = archived_sample
    runner = CliRunner()
    bad = runner.invoke(app, ["query", "units", "--format", "nope", "--archive", str(arch.root)])
    assert bad.exit_code == 2 and "nope" in bad.output
    ok = runner.invoke(app, ["query", "units", "--format", "json", "--archive", str(arch.root)])
    assert ok.exit_code == 0, ok.output
    assert json.loads(ok.output)[0]["serial"] == "MPU0001"


def test_only_the_invoked_command_is_built(capsys: pytest.CaptureFixture[str]) -> None:
    """The command the first word names is built alone; help, a misspelt command and no
    command get the whole app (every command listed, suggestions)."""
    from pipelines.cli_shared import _invoked

    assert _invoked(app, ["--wide", "history", "MPU0001"]) == {"history"}
    assert _invoked(app, ["query", "units"]) == {"query"}
    assert _invoked(app, ["history", "--help"]) == {"history"}
    assert _invoked(app, ["--version"]) == set()
    for words in ([], ["--help"], ["--version", "--help"], ["histry"], ["--wide"]):
        assert _invoked(app, words) is None, words
    every = list(app.registered_commands), list(app.registered_groups)
    with pytest.raises(SystemExit) as done:
        app(["--version"])
    assert done.value.code == 0 and capsys.readouterr().out.startswith("calib ")
    assert (app.registered_commands, app.registered_groups) == every
    with pytest.raises(SystemExit) as done:
        app(["histry"])
    assert done.value.code == 2 and "Did you mean 'history'" in capsys.readouterr().err


def test_read_only_sqlite_archive_opens_without_psycopg(archived_sample) -> None:
    """The read-only opener (`calib serve`'s start) takes the reader role's name from
    storage.roles; on SQLite that loads no PostgreSQL driver."""
    arch, _ = archived_sample
    code = (
        "import sys\nfrom storage.db import resolve_archive\n"
        "from storage.queries import open_readonly\n"
        f"ro = open_readonly(resolve_archive({str(arch.root)!r}))\n"
        "assert ro.read_only and ro.schema_revision()\n"
        "assert 'psycopg' not in sys.modules, 'psycopg'\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    subprocess.run([sys.executable, "-c", code], check=True, env=env, timeout=120)


@pytest.mark.slow  # fast: test_read_only_sqlite_archive_opens_without_psycopg (serve's opener)
def test_serve_start_loads_no_science_stack(archived_sample) -> None:
    """`calib serve`'s start (the application built on a read-only archive, its lifespan
    run, a page of runs) loads none of the science stack; the unit page loads what it
    fits with when first asked for, and freezes it out of the garbage collector's sight."""
    arch, _ = archived_sample
    code = (
        "import gc, json, sys\nfrom fastapi.testclient import TestClient\n"
        "from pipelines.web.app import create_app\n"
        "from storage.db import resolve_archive\nfrom storage.queries import open_readonly\n"
        f"app = create_app(open_readonly(resolve_archive({str(arch.root)!r})))\n"
        "with TestClient(app) as client:\n"
        "    assert client.get('/runs').status_code == 200\n"
        f"    start = [m for m in {SCIENCE!r} if m in sys.modules]\n"
        "    frozen = gc.get_freeze_count()\n"
        "    assert frozen > 0 and client.get('/units/MPU0001').status_code == 200\n"
        "    assert 'scipy' in sys.modules and gc.get_freeze_count() > frozen\n"
        "print(json.dumps(start))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert json.loads(done.stdout.strip().splitlines()[-1]) == []
