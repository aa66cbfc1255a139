"""One presentation of a number (pipelines.reports.display) in the CLI and the web pages;
the lineage of one parameter at 80 columns; read-only commands that load only what they
use; tables at 80 columns that keep the row's identity and verdict.

The MPU-6000 sample of data_samples/ is processed into a real SQLite archive; the
commands run in-process (CliRunner, 80 columns) and in a fresh interpreter.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from calib_core.units import DEG
from calib_testing.cli_imports import modules_loaded
from pipelines.cli import app
from pipelines.reports.display import check_counts, expanded_u, shown
from storage import queries

ROOT = Path(__file__).resolve().parent.parent
WIDTH = 80


def _run(*args: str) -> str:
    result = CliRunner().invoke(app, list(args), env={"COLUMNS": str(WIDTH)}, terminal_width=WIDTH)
    assert result.exit_code == 0, result.output
    return result.output


def test_shown_rounds_the_value_to_its_uncertainty() -> None:
    s = shown("gyr.bias.x", 2.70721 * DEG, 0.000384 * DEG)
    assert (s.value, s.u, s.unit) == ("2.70721", "0.00038", "deg/s")
    s = shown("acc.bias.x", 123.456, 12.3)  # u of two digits above the decimal point
    assert (s.value, s.u) == ("123", "12")
    assert shown("acc.bias.x", 0.5, None).u == ""
    assert shown("acc.bias.x", math.nan, 0.1).value == "-"
    assert expanded_u(2.0) == "U (k=2)" and expanded_u(1.9623) == "U (k=1.96)"


def test_show_latest_and_web_agree_on_every_number(archived_sample) -> None:
    """`calib show`, `calib query latest` and the run page print each parameter in the
    same display unit with the same digits; JSON stays SI."""
    from pipelines.web.app import create_app
    from storage.queries import open_readonly

    arch, run_id = archived_sample
    summary = queries.run_summary(arch, run_id)
    show = _run("show", run_id, "--archive", str(arch.root))
    latest = _run("query", "latest", "MPU0001", "--archive", str(arch.root))
    ro = open_readonly(arch)
    page = TestClient(create_app(ro)).get(f"/runs/{run_id}").text
    ro.dispose()
    for p in summary.calibration.parameters:
        s = shown(p.name, p.value, p.std)
        for text in (show, latest):
            row = next(line for line in text.splitlines() if f" {p.name} " in line)
            cells = [c.strip() for c in row.strip().strip("│").split("│")]
            assert [s.value, s.u, s.unit] == cells[1:4], row
        assert f">{s.value}</a>" in page and f">{s.u}</td>" in page
    assert "deg/s" in latest and "rad/s" not in latest  # display units, not SI
    doc = json.loads(
        _run("query", "latest", "MPU0001", "--archive", str(arch.root), "--format", "json")
    )
    assert {r["unit"] for r in doc if r["name"].startswith("gyr.bias")} == {"rad/s"}
    # The checks are counted the same way in the terminal and on the page.
    sentence = check_counts(summary.calibration.checks).sentence()
    assert sentence in " ".join(show.split()) and sentence in page
    assert "tolerance checks failed" in sentence


def test_markup_in_values_is_shown_as_written(archived_sample) -> None:
    """A hint naming the manifest's "[site]" table keeps its brackets (rich markup)."""
    arch, run_id = archived_sample
    show = _run("show", run_id, "--archive", str(arch.root))
    assert "[site]" in show


def test_lineage_of_one_parameter_is_readable_at_80_columns(archived_sample) -> None:
    arch, run_id = archived_sample
    text = _run("query", "lineage", run_id, "gyr.scale.x", "--archive", str(arch.root))
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= WIDTH
    assert len(lines) < 120
    summary = queries.run_summary(arch, run_id)
    for f in summary.raw_files:
        assert f.name in text and f"sha256 {f.sha256}" in text
    assert "Step 2: solve" in text and "replaced samples of gyr.x" in text
    assert "Uncertainty budget of gyr.scale.x" in text and "U (k=" in text
    for other in ("acc.bias.x", "gyr.scale.y", "flagged_indices", "{"):
        assert other not in text, other
    full = json.loads(
        _run(
            "query",
            "lineage",
            run_id,
            "gyr.scale.x",
            "--archive",
            str(arch.root),
            "--format",
            "json",
        )
    )
    budgets = next(s for s in full["steps"] if s["name"] == "uncertainty")["statistics"]
    assert "acc.bias.x" in budgets["budgets"]  # --format json: the full record


def test_history_at_80_columns_keeps_identity_and_verdict(archived_sample) -> None:
    arch, run_id = archived_sample
    text = _run("history", "MPU0001", "--archive", str(arch.root))
    row = next(line for line in text.splitlines() if run_id in line)
    assert "pass" in row
    assert max(len(line) for line in text.splitlines() if "│" in line) <= WIDTH
    assert "." not in row.split("│")[3]  # the start time to the second, no microseconds


@pytest.mark.parametrize("args", [["history", "MPU0001"], ["audit", "MPU0001"], ["--version"]])
def test_read_only_commands_do_not_load_the_science_stack(archived_sample, args) -> None:
    """A fresh interpreter: after the command, neither pandas, pyarrow, numpy, scipy,
    matplotlib, Prefect nor WeasyPrint was imported."""
    arch, _ = archived_sample
    heavy = ("pandas", "pyarrow", "numpy", "scipy", "matplotlib", "prefect", "weasyprint", "typst")
    argv = args + (["--archive", str(arch.root)] if args[0] != "--version" else [])
    assert modules_loaded(argv, heavy) == []


def test_query_units_at_80_columns_keeps_identity_and_verdict(archived_sample) -> None:
    arch, run_id = archived_sample
    text = _run("query", "units", "--archive", str(arch.root))
    header = next(line for line in text.splitlines() if "serial" in line)
    assert header.index("serial") < header.index("run id") < header.index("verdict")
    row = next(line for line in text.splitlines() if run_id in line)
    assert "MPU0001" in row and "pass" in row


@pytest.fixture(scope="module")
def reported(archived_sample, tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """`calib show`, the protocol, the HTML certificate (`calib report`) and the web run
    page of the sample run, as text."""
    from pipelines.web.app import create_app
    from storage.queries import open_readonly

    arch, run_id = archived_sample
    out = tmp_path_factory.mktemp("reported")
    _run("report", run_id, "--archive", str(arch.root), "--output", str(out), "--no-pdf")
    ro = open_readonly(arch)
    page = TestClient(create_app(ro)).get(f"/runs/{run_id}").text
    ro.dispose()
    return {
        "show": _run("show", run_id, "--archive", str(arch.root)),
        "protocol": next(out.glob("*_result.txt")).read_text(encoding="utf-8"),
        "certificate": next(out.glob("*_certificate.html")).read_text(encoding="utf-8"),
        "web": page,
    }


def test_checks_are_counted_alike_everywhere(archived_sample, reported) -> None:
    """One count of the run's checks, the lab conditions apart, in the terminal, the
    protocol, the certificate and on the web page; it adds up to the archived checks."""
    from calib_core.conditions import CONDITION_PREFIX, status

    arch, run_id = archived_sample
    checks = queries.run_summary(arch, run_id).calibration.checks
    counts = check_counts(checks)
    conditions = [c for c in checks if c.name.startswith(CONDITION_PREFIX)]
    assert counts.conditions == len(conditions) > 0
    assert counts.tolerance == len(checks) - len(conditions) > 0
    assert counts.failed == sum(status(c) == "fail" for c in checks)
    assert counts.not_recorded + counts.warnings > 0  # the sample records no environment
    sentence = counts.sentence()
    assert f"Checks: {sentence}\n" in reported["protocol"]
    for where in ("show", "certificate", "web"):
        assert sentence in " ".join(reported[where].split()), where
    # every count sentence anywhere is this one: no other way of counting is left
    for where, text in reported.items():
        said = set(re.findall(r"\d+ of \d+ tolerance checks failed", " ".join(text.split())))
        assert said == {sentence.split(";")[0]}, (where, said)


def test_protocol_and_certificate_show_numbers_as_the_cli_does(archived_sample, reported) -> None:
    """Each parameter's line of the protocol and its row of the certificate give the
    value (signed in the protocol, the MPU-6000 manual's layout), the standard
    uncertainty and the unit as `calib show` does; the columns are headed "u"."""
    arch, run_id = archived_sample
    protocol = reported["protocol"].splitlines()
    html = reported["certificate"]
    for p in queries.run_summary(arch, run_id).calibration.parameters:
        s = shown(p.name, p.value, p.std)
        line = next(x for x in protocol if x.startswith(f"{p.name} "))
        assert line.split()[1:4] == [s.signed, s.u, s.unit], line
        assert f"<td>{p.name}</td><td>{s.value}</td><td>{s.u}</td>" in "".join(html.split())
    header = next(x for x in protocol if x.startswith("Parameter "))
    assert header.split()[:3] == ["Parameter", "Value", "u"]
    assert "u: standard uncertainty (k = 1)" in reported["protocol"]
    assert "Std. unc." not in reported["protocol"] and "rad/s" not in reported["protocol"]


def test_audit_is_a_table_at_80_columns(archived_sample, tmp_path, monkeypatch) -> None:
    """`calib audit` on a terminal: a table whose rows start with the event's identity and
    what happened, at most 80 columns, markup in values shown as written; piped (as here
    by default), one event a line, tab-separated, for scripts."""
    from storage.approval import generate_key

    arch, run_id = archived_sample
    key = tmp_path / "jane.key"
    generate_key(key, "[b]Jane[/b] Approver", "a passphrase for the audit table")
    monkeypatch.setenv("CALIB_KEY_PASSPHRASE", "a passphrase for the audit table")
    _run("approve", run_id, "--key", str(key), "--archive", str(arch.root))
    text = _run("audit", "--archive", str(arch.root), "--format", "table")
    lines = text.splitlines()
    header = next(line for line in lines if "seq" in line and "┃" in line)
    order = [header.index(h) for h in ("seq", "run id", "event", "at (UTC)", "what")]
    assert order == sorted(order), header
    assert max(len(line) for line in lines if "│" in line or "┃" in line) <= WIDTH
    rows = [line for line in lines if run_id in line]
    assert any(" archived " in r for r in rows) and any(" approved " in r for r in rows)
    assert any("[b]Jane[/b]" in line for line in lines), text  # not eaten as markup
    assert "\t" not in text and "None" not in text
    piped = _run("audit", "--archive", str(arch.root)).splitlines()
    events = [line.split("\t") for line in piped if "\t" in line]
    assert [e[3] for e in events if e[3] in ("archived", "approved")] == ["archived", "approved"]


def test_a_table_too_wide_for_80_columns_folds_no_word(capsys, monkeypatch) -> None:
    """`print_table` leaves out columns from the right until every word (a date) and every
    no-wrap cell (an id, a verdict) fits whole, then fixes the widths: rich alone folded
    the due date "2027-11-28" into "2027-11-2" and "8" here."""
    from pipelines import cli_shared

    monkeypatch.setattr(cli_shared.out, "width", WIDTH)
    monkeypatch.setitem(cli_shared.DISPLAY, "wide", False)
    columns = ["serial", "run_id", "verdict", "due", "started_at", "interval_months"]
    rows = [
        ["MPU0001", "Rcc38f1e80ffb", "pass", "2027-11-28", "2026-11-28 02:41:14 UTC", "12"],
        ["IMU-R-0003", "Rb44a549cd3e8", "needs review", "2030-06-08", "2026-11-03 09:00 UTC", "43"],
    ]
    cli_shared.print_table("Units due", columns, rows)
    done = capsys.readouterr()
    lines = done.out.splitlines()
    assert max(len(line) for line in lines) <= WIDTH
    for row in rows:
        line = next(line for line in lines if row[1] in line)
        assert row[0] in line and row[2] in line and row[3] in line, line
    for word in ("2026-11-28", "2026-11-03", "02:41:14"):
        assert word in done.out, word
    assert "interval_months" in done.err  # left out, and named


def test_fleet_commands_speak_the_display_unit(archived_sample) -> None:
    """`calib query fleet` (its table and its median line) and `calib fleet` give the
    value in the unit `calib show` uses, not SI."""
    from pipelines.reports.display import quantity

    arch, run_id = archived_sample
    name = "gyr.bias.z"
    p = next(p for p in queries.run_summary(arch, run_id).calibration.parameters if p.name == name)
    s = shown(name, p.value, p.std)
    a = ["--archive", str(arch.root)]
    table = _run("query", "fleet", "MPU-6000", name, *a)
    row = next(line for line in table.splitlines() if run_id in line)
    assert s.value in row and s.u in row, row
    assert f"median {quantity(name, p.value)}" in table and "deg/s" in table
    bins = _run("fleet", "MPU-6000", name, *a)
    assert quantity(name, p.value) in bins, bins
    assert f"{name} across MPU-6000 (deg/s)" in bins
    for text in (table, bins):
        assert "rad/s" not in text and "nan" not in text, text


def test_protocol_and_certificate_show_no_raw_values(reported) -> None:
    """The archived documents a lab signs: no None, nan, Python repr or raw JSON."""
    raw = re.compile(r"\bNone\b|\bnan\b|\bNaN\b|\{'|\{\"|\['|\bTrue\b|\bFalse\b")
    html = re.sub(r"<style.*?</style>|<[^>]+>", " ", reported["certificate"], flags=re.S)
    for where, text in (("protocol", reported["protocol"]), ("certificate", html)):
        found = [text[max(0, m.start() - 40) : m.end() + 40] for m in raw.finditer(text)]
        assert not found, (where, found)


def test_an_uncertainty_alone_and_a_signed_value() -> None:
    """A budget's contribution is written as every u (two significant digits, fixed point,
    display unit); the protocol's values carry their sign."""
    from pipelines.reports.display import uncertainty

    assert uncertainty("gyr.bias.x", 0.000384 * DEG) == "0.00038"
    assert uncertainty("gyr.scale.x", 2.87e-5) == "0.000029"  # not 2.9e-05
    assert uncertainty("gyr.scale.x", None) == "-"
    assert shown("acc.scale.x", 0.0051, 2.1e-5).signed == "+0.005100"
    assert shown("acc.scale.x", -0.0225, 1.9e-5).signed == "-0.022500"
    assert shown("acc.scale.x", None).signed == "-"
