"""The archive's queries on both back ends, against a small archive whose answers are known.

The expected values are the inputs (what was archived must come back exactly:
doubles round-trip bit for bit) and the dates chosen below, so every
tolerance is zero. The scenario (UTC):

unit A1 (MPU-6000), rate table RT-7 due 2024-06-30:
    r1 2024-01-10 08:30  pass  lab 20 C
    r2 2024-03-05 09:00  fail  lab 25 C
    r3 2024-07-02 10:00  pass  lab 30 C  (RT-7 two days overdue), processed again
                                          -> revision 2 (values x2) supersedes revision 1
unit B2 (MPU-6000):
    r4 2024-06-30 23:59  pass  lab 22 C  (on RT-7's due day: still valid)
unit C3 (ADXL355), rate table RT-9 with no due date recorded:
    r5 2024-02-01 12:00  pass  no lab temperature
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, replace
from datetime import UTC, date, datetime, timedelta, timezone
from pathlib import Path

import pandas as pd
import pytest
from test_archive import make_run
from typer.testing import CliRunner

from pipelines.cli import app
from storage import queries
from storage.archive import archive_run
from storage.db import Archive
from storage.run_input import RunIn

RT7 = {
    "kind": "rate_table",
    "serial": "RT-7",
    "model": "AC1120",
    "accuracy_class": "0.01%",
    "calibration_due": "2024-06-30",
    "calibrated_on": "2023-06-30",
}
RT9 = {"kind": "rate_table", "serial": "RT-9", "model": "X", "calibration_due": None}


def _run(tmp: Path, name: str, serial: str, seed: int, when: datetime, **kw) -> RunIn:
    run = make_run(tmp / name, serial=serial, seed=seed, started_at=when)
    return replace(run, **kw)


@dataclass
class Scenario:
    runs: dict[str, RunIn]  # r1..r5 as first archived; "r3b" the revision 2 of r3
    ids: dict[str, str]  # run ids


def build(archive: Archive, tmp: Path) -> Scenario:
    t = lambda *a: datetime(*a, tzinfo=UTC)  # noqa: E731
    # name: serial, k, start, equipment, environment, other fields
    table = {
        "r1": ("A1", 1, t(2024, 1, 10, 8, 30), RT7, {"temperature_c": 20.0}, {}),
        "r2": ("A1", 2, t(2024, 3, 5, 9, 0), RT7, {"temperature_c": 25.0}, {"verdict": "fail"}),
        "r3": ("A1", 3, t(2024, 7, 2, 10, 0), RT7, {"temperature_c": 30.0}, {}),
        "r4": ("B2", 4, t(2024, 6, 30, 23, 59), RT7, {"temperature_c": 22.0}, {}),
        "r5": ("C3", 5, t(2024, 2, 1, 12, 0), RT9, {}, {"device_model": "ADXL355"}),
    }
    runs = {
        name: _run(tmp, name, serial, k, start, equipment=[eq], environment=env, **other)
        for name, (serial, k, start, eq, env, other) in table.items()
    }
    ids = {k: archive_run(archive, r).run_id for k, r in runs.items()}
    r3 = runs["r3"]
    runs["r3b"] = replace(
        r3,
        settings={**r3.settings, "outlier_sigma": 4.0},
        software_version="0.2.0",
        source_revision="def456",
        parameters=[replace(p, value=2 * p.value) for p in r3.parameters],
    )
    res = archive_run(archive, runs["r3b"])
    assert (res.status, res.revision) == ("revised", 2)
    return Scenario(runs, ids)


def values(run: RunIn) -> dict[str, float]:
    return {p.name: p.value for p in run.parameters}


@pytest.fixture
def scenario(archive: Archive, tmp_path: Path) -> Scenario:
    return build(archive, tmp_path / "in")


def test_latest_valid_as_of_dates(archive: Archive, scenario: Scenario) -> None:
    r = scenario.runs
    now = queries.latest_valid(archive, "A1")
    # The current revision of the newest passing run: r3 revision 2 (values doubled).
    assert set(now["run_id"]) == {scenario.ids["r3"]} and set(now["revision"]) == {2}
    assert dict(zip(now["name"], now["value"], strict=True)) == values(r["r3b"])
    assert set(now["software_version"]) == {"0.2.0"}
    # Before r3, r2 failed: r1 is the valid one.
    mid = queries.latest_valid(archive, "A1", "2024-07-01")
    assert set(mid["run_id"]) == {scenario.ids["r1"]}
    assert dict(zip(mid["name"], mid["value"], strict=True)) == values(r["r1"])
    # A date includes its whole UTC day; an instant one minute before the run excludes it.
    assert set(queries.latest_valid(archive, "A1", date(2024, 1, 10))["run_id"]) == {
        scenario.ids["r1"]
    }
    assert queries.latest_valid(archive, "A1", "2024-01-10T08:29:00+00:00").empty
    assert queries.latest_valid(archive, "A1", "2024-01-09").empty
    # Zones count: 10:29 at UTC+2 is 08:29 UTC, a minute before r1 (read as UTC it would be after).
    plus2 = timezone(timedelta(hours=2))
    assert queries.latest_valid(archive, "A1", datetime(2024, 1, 10, 10, 29, tzinfo=plus2)).empty
    assert not queries.latest_valid(archive, "A1", "2024-01-10T10:30:00+02:00").empty
    assert queries.latest_valid(archive, "ZZ9").empty
    # The dict API agrees.
    full = queries.latest_calibration(archive, "A1", datetime(2024, 7, 1, tzinfo=UTC))
    assert full.run_id == scenario.ids["r1"]


def test_lineage_of_a_value(archive: Archive, scenario: Scenario) -> None:
    r3, r3b = scenario.runs["r3"], scenario.runs["r3b"]
    rid = scenario.ids["r3"]
    lin = queries.lineage(archive, rid, "acc.bias.x")
    assert lin["parameter"]["values"] == [
        {
            "value": p.value,
            "std": p.std,
            "unit": p.unit,
            "temperature_c": r3b.parameter_temperature_c,
        }
        for p in r3b.parameters
        if p.name == "acc.bias.x"
    ]
    cal = lin["calibration"]
    assert (cal["revision"], cal["current"], cal["superseded_by_revision"]) == (2, True, None)
    assert (cal["software_version"], cal["source_revision"]) == ("0.2.0", "def456")
    assert cal["settings"] == r3b.settings and cal["verdict"] == "pass"
    assert sorted((f["name"], f["sha256"], f["size"]) for f in lin["raw_files"]) == sorted(
        (f.name, f.sha256, f.size) for f in r3.raw_files
    )
    for f in lin["raw_files"]:  # the stored path holds exactly those bytes
        src = next(x for x in r3.raw_files if x.name == f["name"])
        assert (archive.root / f["stored_path"]).read_bytes() == src.path.read_bytes()
    assert [(s["seq"], s["name"], s["settings"]) for s in lin["steps"]] == [
        (i, s.name, s.settings) for i, s in enumerate(r3b.steps)
    ]
    assert lin["run"]["operator"] == r3.operator
    assert lin["run"]["environment"] == r3.environment.as_dict()
    assert lin["run"]["environment"]["temperature_c"] == 30.0
    assert (lin["run"]["site"], lin["run"]["gravity"]) == (r3.site.as_dict(), r3.gravity)
    assert lin["run"]["started_at"] == r3.started_at
    assert lin["device"]["serial"] == "A1"
    (eq,) = lin["equipment"]
    assert (eq["serial"], eq["calibration_due"], eq["valid_at_run"], eq["days_overdue"]) == (
        "RT-7",
        date(2024, 6, 30),
        False,
        2,
    )
    # The superseded revision is still there, and says what superseded it.
    old = queries.lineage(archive, rid, "acc.bias.x", revision=1)
    assert old["calibration"]["current"] is False
    assert old["calibration"]["superseded_by_revision"] == 2
    assert old["parameter"]["values"][0]["value"] == values(r3)["acc.bias.x"]
    assert old["calibration"]["software_version"] == "0.1.0"
    # Equipment valid on its due day (r4 at 23:59 UTC on 2024-06-30).
    (eq4,) = queries.lineage(archive, scenario.ids["r4"], "acc.bias.x")["equipment"]
    assert (eq4["valid_at_run"], eq4["days_overdue"]) == (True, 0)
    (eq5,) = queries.lineage(archive, scenario.ids["r5"], "acc.bias.x")["equipment"]
    assert eq5["valid_at_run"] is None  # no due date recorded: unknown, not valid
    with pytest.raises(LookupError, match="no parameter 'gyr.scale.z'"):
        queries.lineage(archive, rid, "gyr.scale.z")
    with pytest.raises(LookupError, match="no calibration revision 7"):
        queries.lineage(archive, rid, "acc.bias.x", revision=7)
    with pytest.raises(LookupError, match="no run"):
        queries.lineage(archive, "R000000000000", "acc.bias.x")
    with pytest.raises(ValueError, match="not a canonical parameter name"):
        queries.lineage(archive, rid, "acc.bias.x' OR 1=1 --")


def test_lapsed_equipment(archive: Archive, scenario: Scenario) -> None:
    df = queries.lapsed_runs(archive, "RT-7")
    # Only r3 (2 days after the due date); r4 on the due day itself is within it.
    assert df["run_id"].tolist() == [scenario.ids["r3"]]
    assert df["serial"].tolist() == ["A1"]
    assert df["days_overdue"].tolist() == [2]
    assert df["calibration_due"].tolist() == [date(2024, 6, 30)]
    assert queries.lapsed_runs(archive, "RT-7", kind="centrifuge").empty
    assert queries.lapsed_runs(archive, "RT-9").empty  # no due date: never counted as lapsed
    assert queries.lapsed_runs(archive, "RT-7' OR '1'='1").empty  # a bound value, not SQL


def test_units_filters(archive: Archive, scenario: Scenario) -> None:
    ids = scenario.ids

    def runs(**kw) -> list[str]:
        return queries.units(archive, **kw)["run_id"].tolist()

    assert runs() == [ids[k] for k in ("r1", "r5", "r2", "r4", "r3")]  # by start time
    assert runs(model="MPU-6000") == [ids[k] for k in ("r1", "r2", "r4", "r3")]
    assert runs(model="ADXL355") == [ids["r5"]]
    assert runs(verdict="fail") == [ids["r2"]]
    assert runs(date_from="2024-03-05", date_to="2024-06-30") == [ids["r2"], ids["r4"]]
    assert runs(date_from="2024-03-06", date_to="2024-06-29") == []
    assert runs(env_temp_min=24.0) == [ids["r2"], ids["r3"]]
    assert runs(env_temp_min=22.0, env_temp_max=25.0) == [ids["r2"], ids["r4"]]
    assert runs(model="MPU-6000", verdict="pass", env_temp_max=21.0) == [ids["r1"]]
    df = queries.units(archive, model="MPU-6000")
    # r3 is listed once, with its current revision.
    assert df.loc[df["run_id"] == ids["r3"], "revision"].tolist() == [2]
    assert df["env_temperature_c"].tolist() == [20.0, 25.0, 22.0, 30.0]
    assert runs(model="MPU-6000' OR '1'='1") == []


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"verdict": "maybe"}, "verdict: expected one of pass, fail"),
        ({"date_from": "2024-13-01"}, "date_from: expected a date"),
        ({"date_to": "2024-05-01T08:00:00"}, "date_to: .* has no time zone"),
        ({"date_from": "2024-05-02", "date_to": "2024-05-01"}, "is after"),
        ({"env_temp_min": 30.0, "env_temp_max": 20.0}, "min 30.0 is above max 20.0"),
        ({"env_temp_min": float("nan")}, "env_temp_min: expected a finite number"),
        ({"model": ""}, "model: expected 1-200 printable characters"),
    ],
)
def test_invalid_filters_are_refused_with_a_clear_message(
    tmp_path: Path, kwargs: dict, message: str
) -> None:
    # Validation happens before any SQL: an archive without a database will do.
    nowhere = Archive("sqlite:///" + str(tmp_path / "none.sqlite"), tmp_path)
    with pytest.raises(ValueError, match=message):
        queries.units(nowhere, **kwargs)
    assert not (tmp_path / "none.sqlite").exists()


def test_parameter_history_and_fleet(archive: Archive, scenario: Scenario) -> None:
    r = scenario.runs
    h = queries.serial_parameter_history(archive, "A1", "acc.scale.z")
    assert h["run_id"].tolist() == [scenario.ids[k] for k in ("r1", "r2", "r3")]
    assert h["value"].tolist() == [values(r[k])["acc.scale.z"] for k in ("r1", "r2", "r3b")]
    assert h["verdict"].tolist() == ["pass", "fail", "pass"]
    full = queries.serial_parameter_history(archive, "A1", "acc.scale.z", include_superseded=True)
    assert full["revision"].tolist() == [1, 1, 1, 2]
    with pytest.raises(ValueError, match="invalid serial"):
        queries.serial_parameter_history(archive, "../A1", "acc.scale.z")

    f = queries.fleet(archive, "MPU-6000", "gyr.bias.x")
    assert f["serial"].tolist() == ["A1", "B2"]
    assert f["run_id"].tolist() == [scenario.ids["r3"], scenario.ids["r4"]]
    assert f["value"].tolist() == [values(r["r3b"])["gyr.bias.x"], values(r["r4"])["gyr.bias.x"]]
    early = queries.fleet(archive, "MPU-6000", "gyr.bias.x", as_of="2024-06-01")
    assert early["serial"].tolist() == ["A1"]
    assert early["value"].tolist() == [values(r["r1"])["gyr.bias.x"]]
    assert queries.fleet(archive, "ADXL355", "gyr.bias.x")["serial"].tolist() == ["C3"]
    assert queries.fleet(archive, "MPU-6000", "gyr.gsens.xy").empty


def test_cli_query_formats(archive: Archive, scenario: Scenario, monkeypatch) -> None:  # noqa: ANN001
    monkeypatch.setenv("CALIB_FILESTORE", str(archive.root))
    cli = CliRunner()

    def call(*args: str):  # noqa: ANN202
        return cli.invoke(app, ["query", *args, "--archive", archive.url])

    res = call("latest", "A1", "--at", "2024-07-01", "--format", "json")
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert {d["run_id"] for d in doc} == {scenario.ids["r1"]}
    assert {d["name"]: d["value"] for d in doc} == values(scenario.runs["r1"])
    assert doc[0]["started_at"].startswith("2024-01-10T08:30:00")

    res = call("history", "A1", "acc.bias.x", "--format", "csv")
    assert res.exit_code == 0, res.output
    csv = pd.read_csv(io.StringIO(res.stdout))
    expected = queries.serial_parameter_history(archive, "A1", "acc.bias.x")
    assert csv["value"].tolist() == expected["value"].tolist()  # repr round-trips doubles

    res = call("lineage", scenario.ids["r3"], "acc.bias.x", "--format", "json")
    assert res.exit_code == 0, res.output
    lin = json.loads(res.stdout)
    assert lin["equipment"][0]["days_overdue"] == 2 and lin["calibration"]["revision"] == 2

    res = call("lapsed", "RT-7", "--format", "json")
    assert [d["run_id"] for d in json.loads(res.stdout)] == [scenario.ids["r3"]]
    res = call("fleet", "MPU-6000", "gyr.bias.x")  # table
    assert res.exit_code == 0 and "A1" in res.stdout and "B2" in res.stdout
    res = call("units", "--model", "MPU-6000", "--verdict", "fail", "--format", "json")
    assert [d["run_id"] for d in json.loads(res.stdout)] == [scenario.ids["r2"]]

    res = call("units", "--verdict", "maybe")
    assert res.exit_code == 2 and "verdict: expected one of pass, fail" in res.stderr
    res = call("latest", "A1", "--at", "2023-01-01", "--format", "json")
    assert res.exit_code == 1 and json.loads(res.stdout) == []


def test_latest_run_and_fleet_pick_follow_the_current_rule(archive: Archive, tmp_path: Path):
    """storage.current decides a unit's latest run and latest valid calibration: of two
    runs started at one instant the later archived, whatever their run ids' order (the
    run id text sorts the other way here); a later failed run leaves the valid one."""
    from storage.run_input import raw_hash_of, run_id_of

    t = datetime(2025, 1, 2, 8, 0, tzinfo=UTC)
    pair = [_run(tmp_path, f"t{k}", "T1", 40 + k, t) for k in range(2)]
    pair.sort(key=lambda r: run_id_of(raw_hash_of([f.sha256 for f in r.raw_files])))
    first, second = pair[1], replace(pair[0], procedure="static_bias")  # later: smaller id
    ids = [archive_run(archive, r).run_id for r in (first, second)]
    assert ids[1] < ids[0]
    latest = queries.latest_run(archive, "T1")
    assert (latest["run_id"], latest["procedure"], latest["revision"]) == (ids[1], "static_bias", 1)
    assert queries.latest_run(archive, "NONE-1") is None
    failed = _run(tmp_path, "t3", "T1", 43, t + timedelta(days=1), verdict="fail")
    assert archive_run(archive, failed).run_id
    assert queries.latest_run(archive, "T1")["verdict"] == "fail"
    model = first.device_model
    picks = {u["serial"]: u["run_id"] for u in queries.fleet_latest_valid(archive, model)}
    assert picks == {"T1": ids[1]}
    assert queries.fleet_latest_valid(archive, "NO-SUCH-MODEL") == []


@pytest.mark.parametrize(
    "words",
    [
        ["query", "latest", "A1"],
        ["query", "fleet", "MPU-6000", "acc.bias.x"],
        ["thermal", "show", "A1"],
        ["thermal", "export", "A1", "out.json"],
        ["apply", "in", "out.csv", "--serial", "A1"],
    ],
)
def test_every_at_option_reads_one_rule(archive: Archive, tmp_path: Path, words) -> None:  # noqa: ANN001
    """`--at` of every command: a date-time without a zone is refused naming the option,
    what was expected and what was found; a text that is no date likewise."""
    cli = CliRunner()
    for at, said in [
        ("2024-07-01T08:00:00", "--at: 2024-07-01T08:00:00 has no time zone (add +00:00 or Z)"),
        ("July", "--at: expected a date YYYY-MM-DD or a date-time with a zone"),
    ]:
        args = [w if w not in ("in", "out.csv", "out.json") else str(tmp_path / w) for w in words]
        res = cli.invoke(app, [*args, "--at", at, "--archive", archive.url])
        assert res.exit_code == 2 and said in res.stderr, res.output


def test_at_with_a_zone_and_json_records_keep_the_full_values(
    archive: Archive, scenario: Scenario
) -> None:
    """`--at` with a zone is the same instant in any zone; `calib history --json` and
    `calib query --format json` write times with their microseconds and offset
    (``isoformat``) and every double whole (repr round-trips)."""
    cli = CliRunner()
    docs = []
    for at in ("2024-07-01T08:00:00Z", "2024-07-01T10:00:00+02:00"):
        res = cli.invoke(app, ["query", "latest", "A1", "--at", at, "--archive", archive.url])
        assert res.exit_code == 0, res.output
        docs.append(res.stdout)
    assert docs[0] == docs[1] and scenario.ids["r1"] in docs[0]
    res = cli.invoke(app, ["history", "A1", "--archive", archive.url, "--json"])
    assert res.exit_code == 0, res.output
    held = queries.history(archive, "A1")
    assert [r["created_at"] for r in json.loads(res.stdout)] == [
        t.isoformat() for t in held["created_at"]
    ]
    res = cli.invoke(
        app,
        ["query", "history", "A1", "acc.bias.x", "--archive", archive.url, "--format", "json"],
    )
    expected = queries.serial_parameter_history(archive, "A1", "acc.bias.x")
    assert [r["std"] for r in json.loads(res.stdout)] == expected["std"].tolist()


def test_json_records_are_strict_json() -> None:
    """JSON has no NaN or infinity: a table's non-finite numbers are null (as pandas'
    to_json gave them before), so every JSON parser reads `--json` output."""
    from pipelines.cli_shared import frame_records

    df = pd.DataFrame({"std": [float("inf"), float("-inf"), float("nan"), 1.5e-11]})
    records = frame_records(df)
    assert records == [{"std": None}, {"std": None}, {"std": None}, {"std": 1.5e-11}]
    json.dumps(records, allow_nan=False)
