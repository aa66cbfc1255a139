"""The uncertainty budget of a run: coverage on simulated runs, the decision rule in the
run's checks, and the budget in the archive, the protocol and the certificate (HTML and PDF)."""

from __future__ import annotations

import copy
import json
import tomllib
from datetime import date, timedelta
from pathlib import Path

import numpy as np
import pytest

from calib_core import procedures
from calib_core.calibration import Calibration
from calib_core.checks import check_parameters, overall_verdict
from calib_core.conditions import status as condition_status
from calib_core.decision import COND_FAIL, COND_PASS, DecisionRule
from calib_core.run_budget import run_budgets
from calib_core.simulate import random_errors, six_position_integral_run
from calib_core.tolerances import ToleranceProfile
from calib_core.uncertainty import budgets as make_budgets
from calib_core.uncertainty_sources import EquipmentSpec
from calib_core.units import STANDARD_GRAVITY
from calib_core.verification import FAIL, NEEDS_REVIEW
from calib_testing.lab_profile import CUSTOMER, lab_toml
from calib_testing.run_writers import six_position_manifest, write_csv_run
from pipelines.ingest import discover_runs
from pipelines.process import process_run
from pipelines.reports.run_reports import ArchivedRun, report_run
from pipelines.tolerances import SHIPPED
from storage import queries
from storage.db import resolve_archive
from storage.queries.records import RunSummary, Step

G_U = 0.02  # m/s^2, expanded (k = 2) uncertainty of the gravity the simulated runs use


def _coverage_runs(n_runs: int) -> tuple[int, int]:
    """(hits, intervals) of the 95 % intervals of simulated six-position runs.

    Known truth: the error model, white noise, and the true local gravity drawn from the
    stated normal distribution (U = G_U at k = 2) while the solver is given 9.80665 m/s^2;
    only gravity is a Type B source (the simulator has no fixture or turn-angle errors).
    """
    rng = np.random.default_rng(2021)
    spec = EquipmentSpec(
        gravity_expanded=G_U, cube_angle=None, table_rate_rel=None, turn_angle=None
    )
    hits = total = 0
    for _ in range(n_runs):
        truth = random_errors(rng)
        g_true = STANDARD_GRAVITY + G_U / 2 * rng.standard_normal()
        run = six_position_integral_run(truth, rng, gravity=g_true, static_s=5.0)
        cal = procedures.solve("six_position", run.segments, STANDARD_GRAVITY, {})
        b = run_budgets(cal, run.segments, {}, spec)
        for name, true in truth.parameters().items():
            if name not in b or ".noise." in name:  # largest per-position std: biased upwards
                continue
            total += 1
            hits += abs(b[name].value - true) <= b[name].U
    return hits, total


def test_budget_covers_the_truth_of_simulated_runs() -> None:
    hits, total = _coverage_runs(12)
    # 12 runs x 24 parameters = 288 intervals; at 95 % the count's binomial std is
    # sqrt(288 0.95 0.05) = 3.7, so 0.90..0.99 is > 3.5 std either side (the intervals of
    # one run share its noise and gravity, which widens the spread a little).
    assert total == 288
    assert 0.90 <= hits / total <= 0.99, hits / total


def test_equipment_unknown_and_unmodelled_procedures_are_type_a_only() -> None:
    rng = np.random.default_rng(5)
    run = six_position_integral_run(random_errors(rng), rng, static_s=5.0)
    cal = procedures.solve("six_position", run.segments, STANDARD_GRAVITY, {})
    unknown = run_budgets(cal, run.segments, {}, None)["acc.scale.x"]
    known = run_budgets(cal, run.segments, {}, EquipmentSpec())["acc.scale.x"]
    assert unknown.type_a_only and unknown.label == "Type A only (equipment unknown)"
    assert not known.type_a_only and known.U > unknown.U
    other = Calibration(procedure="centrifuge", gravity=STANDARD_GRAVITY)
    other.add("acc.scale.x", 0.01, 1e-4)
    b = run_budgets(other, {}, {}, EquipmentSpec())["acc.scale.x"]
    assert b.type_a_only and "procedure 'centrifuge' not modelled" in b.label


def _judged(value: float, U: float, rule: DecisionRule):
    cal = Calibration(procedure="six_position", gravity=STANDARD_GRAVITY)
    cal.add("acc.scale.x", value, U / 2)
    budgets = make_budgets(lambda v: {"acc.scale.x": value}, [], {"acc.scale.x": (U / 2, 1e9)})
    profile = ToleranceProfile("t", "1", "X", [], decision_rule=rule)
    profile.parameter_limits = ToleranceProfile.from_dict(
        {
            "name": "t",
            "version": "1",
            "device_model": "X",
            "limits": [{"pattern": "acc.scale.*", "bound": 0.01, "unit": "1"}],
        }
    ).parameter_limits
    (check,) = check_parameters(cal, profile, budgets)
    return check, budgets["acc.scale.x"].U


@pytest.mark.parametrize(
    ("value", "verdict", "overall"),
    [
        (0.0070, "pass", "pass"),
        (0.0095, COND_PASS, NEEDS_REVIEW),
        (0.0105, COND_FAIL, FAIL),
        (0.0140, "fail", FAIL),
    ],
)
def test_guard_band_verdicts_in_the_run_checks(value, verdict, overall) -> None:
    # U = 1.96 u with u = 0.001: w = U ~ 0.00196; the limit is 0.01.
    check, U = _judged(value, 0.002 / 1.0204, DecisionRule("guard_band"))
    assert f"; {verdict} (rule guard_band, U = {U:.3g} 1" in check.detail
    assert check.passed == (verdict == "pass")
    assert overall_verdict([check]) == overall
    simple, _ = _judged(0.0095, 0.002, DecisionRule("simple"))
    assert simple.passed and "; pass (rule simple" in simple.detail


# --- the archived run, its protocol and certificate ------------------------------------------

ACC_SCALE_X = 0.0100  # truth, inside the 0.011 limit of the profile below by less than U


def _guarded_profile(folder: Path) -> Path:
    """The shipped mpu6000 profile with a guard band (w = U) and acc.scale.x within 0.011."""
    text = (SHIPPED / "mpu6000.toml").read_text()
    text = text.replace('name = "mpu6000"', 'name = "guarded"')
    text = text.replace(
        'decision_rule = { name = "simple" }', 'decision_rule = { name = "guard_band" }'
    )
    # these runs hold 5 s per attitude (the uncertainty they test is sized by it): the
    # procedure's record >= 10 s (calib_core.conditions) is relaxed to what they hold
    text = text.replace("sample_rate_hz = {", "record_s = { low = 4.9 }\nsample_rate_hz = {")
    first = text.index("[[limits]]")
    limit = '[[limits]]\npattern = "acc.scale.x"\nbound = 0.011\nunit = "1"\n\n'
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "guarded.toml").write_text(text[:first] + limit + text[first:])
    (folder / "lab.toml").write_text(LAB_TOML)
    return folder


LAB_TOML = lab_toml(
    customer=CUSTOMER | {"contact": "qa@example.com"},
    authorised_by={"name": "Dr. A. Metrologist", "function": "Head of calibration"},
    equipment=[{"serial": "CUBE-1", "certificate": "DAkkS 4711-2026", "issued_by": "PTB"}],
)


def _manifest(serial: str, equipment: bool, day: int = 20) -> dict:
    m = six_position_manifest(serial, started=f"2026-11-{day}T09:00:00+00:00")
    # standard gravity (U(g) = 0.03 m/s^2): acc.scale U ~ 3e-3
    m["run"]["tolerance_profile"] = "guarded"
    cube = {"kind": "cube", "model": "PC-100", "serial": "CUBE-1", "calibration_due": "2027-11-15"}
    return m | {"format": {"acc_unit": "g"}, "equipment": [cube] if equipment else []}


# serial -> (equipment named, [(day, true acc.scale.x)]): U-BARE comes back a day later with
# its scale factor drifted by -0.002 (as found / as left).
RUNS = {
    "U-KNOWN": (True, [(20, ACC_SCALE_X)]),
    "U-BARE": (False, [(19, ACC_SCALE_X), (20, ACC_SCALE_X - 0.002)]),
}


@pytest.fixture(scope="module")
def archived(tmp_path_factory: pytest.TempPathFactory):
    """Simulated runs processed into a real SQLite archive; each serial's last run reported."""
    tmp = tmp_path_factory.mktemp("budget-run")
    arch = resolve_archive(str(tmp / "archive"))
    arch.upgrade()
    out = {"archive": arch, "profiles": tmp / "profiles"}
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("CALIB_PROFILES", str(_guarded_profile(tmp / "profiles")))
        for serial, (equipment, days) in RUNS.items():
            for day, scale_x in days:
                rng = np.random.default_rng(7)
                truth = copy.deepcopy(random_errors(rng))
                truth.acc_M[np.diag_indices(3)] = scale_x, 0.0, -0.005  # y, z clear of limits
                truth.gyr_noise[:] = np.radians(0.01)  # within the profile's 0.05 deg/s
                run = six_position_integral_run(truth, rng, static_s=5.0)
                folder = tmp / f"{serial}-{day}"
                write_csv_run(dict(run.segments), folder, _manifest(serial, equipment, day))
                (source,) = discover_runs([folder])
                outcome = process_run(source, arch)
                assert outcome["status"] == "ok", outcome["error"]
                if day == 19:
                    out["earlier"] = queries.run_summary(arch, outcome["run_id"])
            summary = queries.run_summary(arch, outcome["run_id"])
            files = report_run(arch, outcome["run_id"], tmp / f"{serial}-reports")
            import pypdf  # loaded by the test that reads the PDF, not at collection

            pages = [p.extract_text() for p in pypdf.PdfReader(files["pdf"]).pages]
            pdf = "\n".join(pages)
            out[f"{serial}/pages"] = pages
            out[serial] = (
                outcome,
                summary,
                files["html"].read_text(),
                pdf,
                files["protocol"].read_text(),
            )
    return out


@pytest.mark.slow
def test_budget_archived_per_parameter(archived) -> None:
    outcome, summary, *_ = archived["U-KNOWN"]
    budgets = summary.calibration.budgets()
    with_std = {p.name for p in summary.calibration.parameters if p.std is not None}
    assert set(budgets) == with_std
    scale = budgets["acc.scale.x"]
    assert scale["label"] == "Type A + Type B" and scale["coverage"] == 0.95
    # Gravity dominates: d scale / d g = -(1 + s) / g, u(g) = 0.03 / 2 -> u ~ 1.5e-3.
    top = max(scale["rows"], key=lambda r: r["contribution"])
    assert top["source"] == "gravity"
    assert top["contribution"] == pytest.approx(
        (1 + ACC_SCALE_X) * 0.015 / STANDARD_GRAVITY, rel=0.01
    )
    assert scale["U"] == pytest.approx(scale["k"] * scale["uc"])
    said = summary.calibration.step_settings("uncertainty")
    assert said["equipment_spec"]["gravity_expanded"] == 0.03
    assert said["equipment"] == ["cube"]
    assert archived["U-BARE"][1].calibration.budgets()["acc.scale.x"]["label"] == (
        "Type A only (equipment unknown)"
    )


def test_guard_band_verdict_of_the_run(archived) -> None:
    outcome, summary, *_ = archived["U-KNOWN"]
    check = next(c for c in summary.calibration.checks if c.name == "param:acc.scale.x")
    assert f"; {COND_PASS} (rule guard_band" in check.detail and not check.passed
    # lab conditions this simulated run does not record are not failures (calib_core.conditions)
    failed = [c.name for c in summary.calibration.checks if condition_status(c) == "fail"]
    assert failed == ["param:acc.scale.x"]
    assert outcome["verdict"] == NEEDS_REVIEW


def _expected_rows(summary: RunSummary) -> list[tuple[str, str]]:
    from pipelines.reports.display import display

    budgets = summary.calibration.budgets()
    return [(name, f"{display(name, b['U'])[0]:.2g}") for name, b in budgets.items()]


@pytest.mark.parametrize("form", ["html", "pdf"])
def test_certificate_states_uncertainty_and_rule(archived, form) -> None:
    _, summary, html, pdf, _ = archived["U-KNOWN"]
    text = html if form == "html" else pdf
    assert "Measurement uncertainty and statement of conformity" in text
    assert "guarded acceptance" in text and "w = 1 U" in text
    assert "conditional pass" in text
    assert "Coverage factor k" in text and "about 95 %" in text
    assert "Uncertainty budget: dominant contributions" in text
    for name, U in _expected_rows(summary):
        assert name in text and U in text, (name, U)
    assert "Type A + Type B" in text
    assert "Type A only (equipment unknown)" in archived["U-BARE"][2 if form == "html" else 3]


def test_protocol_has_the_uncertainty_table(archived) -> None:
    _, summary, _, _, protocol = archived["U-KNOWN"]
    assert "Measurement uncertainty (GUM)" in protocol
    assert "Decision rule: guarded acceptance" in protocol
    line = next(x for x in protocol.splitlines() if x.startswith("acc.scale.x") and "gravity" in x)
    assert COND_PASS in line


def test_equipment_spec_from_the_manifest() -> None:
    from pipelines.ingest.manifest import run_manifest
    from pipelines.uncertainty import equipment_spec

    doc = {**_manifest("S", equipment=True), "format": {"kind": "csv"}}
    m = run_manifest(doc)
    spec = equipment_spec(m)
    assert spec.gravity_expanded == 3e-2 and spec.cube_angle is not None
    assert spec.table_rate_rel is None  # no rate table named
    doc["run"]["settings"] = {"uncertainty": {"cube_angle_deg": 0.01, "table_rate_rel": 5e-5}}
    spec = equipment_spec(run_manifest(doc))
    assert spec.cube_angle == pytest.approx(np.radians(0.01)) and spec.table_rate_rel == 5e-5
    doc["run"]["settings"] = {"uncertainty": {"cube_angle": 0.01}}
    with pytest.raises(
        ValueError,
        match="run.settings.uncertainty.cube_angle: unknown setting.*did you mean cube_angle_deg",
    ):
        equipment_spec(run_manifest(doc))
    doc["run"]["settings"] = {"uncertainty": {"cube_angle_deg": -1}}
    with pytest.raises(
        ValueError, match="uncertainty.cube_angle_deg: expected a non-negative number, got -1"
    ):
        equipment_spec(run_manifest(doc))
    doc = {**_manifest("S", equipment=False), "format": {"kind": "csv"}}
    assert equipment_spec(run_manifest(doc)) is None


def test_equipment_accuracy_class_read_when_it_states_one() -> None:
    from pipelines.ingest.manifest import run_manifest
    from pipelines.uncertainty import accuracy_of, equipment_spec_sources

    assert accuracy_of("0.01 deg") == ("angle", pytest.approx(np.radians(0.01)))
    assert accuracy_of("36 arcsec") == ("angle", pytest.approx(np.radians(0.01)))
    assert accuracy_of("0.005 %") == ("relative", pytest.approx(5e-5))
    assert accuracy_of("1 ms timestamp") is None and accuracy_of(None) is None
    doc = {**_manifest("S", equipment=True), "format": {"kind": "csv"}}
    doc["equipment"] = [
        {**doc["equipment"][0], "accuracy_class": "0.01 deg"},
        {
            "kind": "rate_table",
            "model": "T",
            "serial": "RT-1",
            "accuracy_class": "100 ppm",
            "calibration_due": "2027-11-15",
        },
        {
            "kind": "daq",
            "model": "D",
            "serial": "D-1",
            "accuracy_class": "1 ms timestamp",
            "calibration_due": "2027-11-15",
        },
    ]
    spec, sources = equipment_spec_sources(run_manifest(doc))
    assert spec.cube_angle == pytest.approx(np.radians(0.01))
    assert spec.table_rate_rel == pytest.approx(1e-4)
    assert sources["cube_angle"] == "accuracy_class '0.01 deg' of cube CUBE-1"
    assert sources["turn_angle"] == "default"


def _as_found_step(summary: RunSummary) -> Step:
    return summary.calibration.step("as_found")


def test_as_found_archived_for_a_recalibrated_unit(archived) -> None:
    """U-BARE's earlier calibration applied to its new run's samples (pipelines.as_found)."""
    _, summary, *_ = archived["U-BARE"]
    step = _as_found_step(summary)
    earlier = archived["earlier"]
    assert step.settings["earlier_run_id"] == earlier.run_id
    assert step.settings["earlier_started_at"].startswith("2026-11-19")
    rows = {r["parameter"]: r for r in step.statistics["parameters"]}
    before = {p.name: p for p in earlier.calibration.parameters}
    after = {p.name: p.value for p in summary.calibration.parameters}
    assert set(rows) == {n for n in after if ".noise." not in n}
    scale = rows["acc.scale.x"]
    assert scale["earlier"] == before["acc.scale.x"].value
    assert scale["as_left"] == after["acc.scale.x"]
    # The truth drifted by d = -0.002: as found d / (1 + s_old) up to second order in the
    # earlier misalignments (|d| 0.01), within 5 std of both fits (the earlier estimate's
    # error stays in the corrected samples, the new solve adds its own).
    s_old, std_old = before["acc.scale.x"].value, before["acc.scale.x"].std
    bound = 5 * np.hypot(scale["std"], std_old) + 0.002 * 0.01
    assert abs(scale["error"] - (-0.002) / (1 + s_old)) <= bound, (scale, bound)
    assert abs(scale["error"]) > 5 * bound
    # The parameters that did not drift: zero as found, within the same noise bound.
    for name in ("acc.scale.y", "acc.bias.x", "gyr.scale.z", "gyr.bias.y"):
        r = rows[name]
        assert abs(r["error"]) <= 5 * np.hypot(r["std"], before[name].std), (name, r)
    budgets = summary.calibration.budgets()
    assert scale["U"] == budgets["acc.scale.x"]["U"] and scale["k"] == budgets["acc.scale.x"]["k"]
    assert scale["verdict"] == "pass"  # |-0.002| within the 0.011 limit less w = U (~ 3e-5)
    assert archived["U-KNOWN"][1].calibration.step("as_found") is None


@pytest.mark.parametrize("form", ["html", "pdf"])
def test_as_found_and_as_left_of_a_recalibrated_unit(archived, form) -> None:
    _, summary, html, pdf, _ = archived["U-BARE"]
    text = html if form == "html" else pdf
    assert "As found / as left (ISO/IEC 17025:2017 7.8.4.2)" in text
    earlier = archived["earlier"]
    assert f"run {earlier.run_id} of 2026-11-19, revision 1" in text
    assert "error model solved again on the corrected" in " ".join(text.split())
    from pipelines.reports.display import display

    rows = {r["parameter"]: r for r in _as_found_step(summary).statistics["parameters"]}
    scale = rows["acc.scale.x"]
    for shown in (
        f"{scale['earlier']:+.6g}",
        f"{scale['as_left']:+.6g}",
        f"{scale['error']:+.3g}",
        f"{display('acc.scale.x', scale['U'])[0]:.2g}",
    ):
        assert shown in text, shown
    assert "No earlier valid calibration" in archived["U-KNOWN"][2 if form == "html" else 3]


# ISO/IEC 17025:2017 items of a certificate the archive and the lab profile know.
ITEMS = {
    "7.8.2.1 a title": "Calibration certificate MPU-6000 U-KNOWN",
    "7.8.2.1 b laboratory": "IMU Lab GmbH, Musterstrasse 1, 80331 Muenchen, Germany",
    "7.8.2.1 e customer": "Example Drones AG, qa@example.com",
    "7.8.2.1 f method": "procedure six_position_integral",
    "7.8.2.1 g item": "MPU-6000, serial U-KNOWN, made by InvenSense",
    "7.8.2.1 i date of calibration": "Date of calibration",
    "7.8.2.1 l only the item": "The results relate only to the item calibrated",
    "7.8.2.1 m results with units": "(deg/s)/g",
    "7.8.2.1 o authorised by": "Dr. A. Metrologist, Head of calibration",
    "7.8.4.1 a uncertainty": "coverage probability about 95 %",
    "7.8.4.1 b conditions": "20.0 deg C",
    "7.8.4.1 c traceability": "DAkkS 4711-2026",
    "7.8.6 decision rule": "Decision rule: guarded acceptance",
}


@pytest.mark.parametrize("form", ["html", "pdf"])
@pytest.mark.parametrize("item", sorted(ITEMS))
def test_certificate_item(archived, item, form) -> None:
    _, summary, html, pdf, _ = archived["U-KNOWN"]
    assert ITEMS[item] in (html if form == "html" else pdf)


@pytest.mark.parametrize("form", ["html", "pdf"])
def test_certificate_number_dates_and_end(archived, form) -> None:
    _, summary, html, pdf, _ = archived["U-KNOWN"]
    text = html if form == "html" else pdf
    number = f"{summary.run_id}-{summary.calibration.revision}"
    assert "Certificate number" in text and number in text
    assert "2026-11-20" in text and "Date of issue" in text
    issued = {(date.today() + timedelta(days=d)).isoformat() for d in (-1, 0, 1)}
    assert any(f"{d}" in text for d in issued)  # today (UTC), whatever the local date
    assert f"End of certificate {number}" in text
    if form == "pdf":  # 7.8.2.1 d: the number and page x of y on every page
        pages = archived["U-KNOWN/pages"]
        for i, page in enumerate(pages, start=1):
            assert number in page and f"page {i} of {len(pages)}" in page, i


def test_lab_profile_checked_and_missing_items_said(archived, tmp_path, monkeypatch) -> None:
    from pipelines.lab import load_lab_profile
    from pipelines.reports.iso17025 import NOT_RECORDED, administrative_section

    monkeypatch.setenv("CALIB_PROFILES", str(tmp_path))
    assert load_lab_profile() is None
    (tmp_path / "lab.toml").write_text('[laboratory]\nname = "X"\nphone = "1"\n')
    with pytest.raises(
        ValueError,
        match=r"lab.toml line 3: laboratory.phone: unknown field of \[laboratory\]; "
        r"expected one of accreditation, address, country, name$",
    ):
        load_lab_profile()
    (tmp_path / "lab.toml").write_text('[laboratory]\nname = "X"\n')
    with pytest.raises(
        ValueError, match=r"lab.toml: laboratory.address: required field is missing"
    ):
        load_lab_profile()
    pairs = dict(administrative_section(ArchivedRun(archived["U-KNOWN"][1])).pairs)
    assert pairs["Calibration laboratory"] == NOT_RECORDED == pairs["Customer"]


def _as_list(node) -> list:
    """dccXMLJSONConv gives a repeated element as a list, a single one as a dict."""
    return node if isinstance(node, list) else [node]


def _read_dcc(xml: str) -> dict:
    """The DCC read back with dccXMLJSONConv (PTB's DCC XML <-> JSON converter, a reader written
    by others): the root element as the reader's dict."""
    import warnings

    from dccXMLJSONConv.dccConv import XMLToJson

    with warnings.catch_warnings():  # it warns each time a repeated element becomes a list
        warnings.simplefilter("ignore", RuntimeWarning)
        warnings.simplefilter("ignore", DeprecationWarning)  # its importlib.resources call
        return XMLToJson(xml)["dcc:digitalCalibrationCertificate"]


def _dcc_results(xml: str) -> dict[str, dict]:
    """{parameter name: its si:real} of the DCC as dccXMLJSONConv reads it."""
    results = _read_dcc(xml)["dcc:measurementResults"]
    out = {}
    for result in _as_list(results["dcc:measurementResult"]):
        for r in _as_list(result["dcc:results"]["dcc:result"]):
            out[r["dcc:name"]["dcc:content"]["#text"]] = r["dcc:data"]["dcc:quantity"]["si:real"]
    return out


def _assert_dcc_matches_archive(xml: str, summary: RunSummary) -> None:
    """Every archived parameter's value, D-SI unit, U, k and coverage found in the DCC, exactly
    (the writer prints repr(float): the round trip is lossless, so equality, not a tolerance)."""
    from pipelines.reports.dcc import D_SI

    read = _dcc_results(xml)
    budgets = summary.calibration.budgets()
    assert set(read) == {p.name for p in summary.calibration.parameters}
    for p in summary.calibration.parameters:
        real = read[p.name]
        assert float(real["si:value"]["#text"]) == p.value, p.name
        assert real["si:unit"]["#text"] == D_SI[p.unit], p.name
        b, unc = budgets[p.name], real["si:expandedUnc"]
        assert float(unc["si:uncertainty"]["#text"]) == b["U"], p.name
        assert float(unc["si:coverageFactor"]["#text"]) == b["k"], p.name
        assert float(unc["si:coverageProbability"]["#text"]) == b["coverage"] == 0.95


def test_dcc_round_trip(archived, tmp_path, monkeypatch) -> None:
    """`calib report RUN --format dcc` read back: every value and U equal to the archive's.

    Read with dccXMLJSONConv (PTB); pydcc, the reader the issue names, does not import here
    (its oscrypto 1.3.0 cannot parse OpenSSL 3.0.19's version string; docs/reports.md).
    Valid against PTB's DCC 3.3.0 schema (vendored in tests/schemas).
    """
    from typer.testing import CliRunner

    from calib_testing.documents import dcc_schema_errors
    from pipelines.cli import app

    _, summary, *_ = archived["U-KNOWN"]
    monkeypatch.setenv("CALIB_PROFILES", str(archived["profiles"]))
    args = [
        "report",
        summary.run_id,
        "--archive",
        str(archived["archive"].root),
        "--output",
        str(tmp_path),
        "--format",
        "dcc",
        "--json",
    ]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    xml = Path(json.loads(result.stdout)["dcc"]).read_text(encoding="utf-8")
    assert dcc_schema_errors(xml.encode()) == []
    _assert_dcc_matches_archive(xml, summary)
    root = _read_dcc(xml)
    assert root["@schemaVersion"] == "3.3.0"
    assert [k for k in root if not k.startswith("@")] == [
        "dcc:administrativeData",
        "dcc:measurementResults",
    ]
    admin = root["dcc:administrativeData"]
    number = f"{summary.run_id}-{summary.calibration.revision}"
    assert admin["dcc:coreData"]["dcc:uniqueIdentifier"]["#text"] == number
    assert admin["dcc:coreData"]["dcc:endPerformanceDate"]["#text"] == "2026-11-20"
    ident = admin["dcc:items"]["dcc:item"]["dcc:identifications"]["dcc:identification"]
    assert ident["dcc:value"]["#text"] == "U-KNOWN"
    lab = admin["dcc:calibrationLaboratory"]["dcc:contact"]["dcc:name"]["dcc:content"]
    assert lab["#text"] == "IMU Lab GmbH"
    said = [
        s["dcc:declaration"]["dcc:content"]["#text"]
        for s in _as_list(admin["dcc:statements"]["dcc:statement"])
    ]
    assert any(s.startswith("Decision rule: guarded acceptance") for s in said)
    result = root["dcc:measurementResults"]["dcc:measurementResult"]
    condition = result["dcc:influenceConditions"]["dcc:influenceCondition"]
    assert condition["dcc:data"]["dcc:quantity"]["si:real"]["si:unit"]["#text"] == r"\kelvin"


def _broken(xml: str, how: str) -> str:
    """The DCC with one value changed in its last digit, or one element removed."""
    import re

    if how == "value":
        first = re.search(r"<si:value>([^<]*)</si:value>", xml.split("dcc:results>")[1])
        old = first.group(1)
        new = old[:-1] + ("1" if old[-1] != "1" else "2")
        return xml.replace(f"<si:value>{old}</si:value>", f"<si:value>{new}</si:value>", 1)
    if how == "uncertainty":
        return re.sub(r"<si:uncertainty>[^<]*</si:uncertainty>\s*", "", xml, count=1)
    start = xml.rindex("<dcc:result ")
    return xml[:start] + xml[xml.index("</dcc:result>", start) + len("</dcc:result>") :]


@pytest.mark.parametrize("how", ["value", "uncertainty", "result"])
def test_dcc_round_trip_fails_on_a_broken_dcc(archived, how) -> None:
    """The round-trip comparison can fail: a changed value or a missing element is caught."""
    from pipelines.reports.dcc import dcc_xml

    _, summary, *_ = archived["U-KNOWN"]
    xml = dcc_xml(ArchivedRun(summary, lab=tomllib.loads(LAB_TOML))).decode("utf-8")
    _assert_dcc_matches_archive(xml, summary)
    broken = _broken(xml, how)
    assert broken != xml
    with pytest.raises((AssertionError, KeyError)):
        _assert_dcc_matches_archive(broken, summary)
