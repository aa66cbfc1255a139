"""Lab conditions and acquisition rules, judged at the procedure's limits.

Every limit below is the procedure's own number (docs/methods.md 2.4, 3.10): ambient 20 +- 2 deg C,
drift <= 0.5 deg C/h, humidity 40-60 %, warm-up >= 10 min (consumer grade), sampling
>= 100 Hz, resolution >= 16 bit, settle >= 30 s (positions) / >= 20 s (rate points),
record >= 10 s, static temperature spread <= 0.2 deg C, table rate stability <= 0.1 deg/s
and deviation <= 0.5 deg/s. Each is tested just inside and just outside its limit.
"""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from calib_core import conditions
from calib_core.calibration import CheckResult
from calib_core.checks import overall_verdict
from calib_core.recording import Recording
from calib_core.tolerances import ToleranceProfile
from calib_core.units import DEG
from pipelines.cli import app
from pipelines.ingest import discover_runs
from pipelines.process import process_run
from storage.db import resolve_archive

DATA_SAMPLES = Path(__file__).resolve().parent.parent / "data_samples"
RECORDED_OK = {
    "ambient_temperature_c": 20.0, "temperature_drift_c_per_h": 0.1, "humidity_pct": 50.0,
    "pressure_hpa": 1000.0, "warmup_min": 15.0, "resolution_bits": 16.0, "settle_s": 30.0,
}  # fmt: skip


def _static(label: str, seconds: float = 20.0, rate: float = 100.0, temp=None) -> Recording:
    n = int(round(seconds * rate)) + 1
    t = np.arange(n) / rate
    acc = np.tile([0.0, 0.0, 9.81], (n, 1))
    temp = None if temp is None else np.asarray(temp(t), dtype=float)
    return Recording(t=t, acc=acc, gyr=np.zeros((n, 3)), temp=temp, label=label)


def _plateau(label: str, rate_dps: float, std_dps: float, offset_dps: float = 0.0) -> Recording:
    rec = _static(label, 30.0, 100.0)
    noise = np.random.default_rng(1).standard_normal(len(rec))
    noise = (noise - noise.mean()) / noise.std(ddof=1)  # exactly std_dps over the plateau
    table = (rate_dps + offset_dps + std_dps * noise) * DEG
    return Recording(
        t=rec.t, acc=rec.acc, gyr=rec.gyr, reference={"table_rate": table}, label=label
    )


def _checks(segments, recorded=None, *, procedure="six_position", settings=None, source="site"):
    segs = {r.label: r for r in segments}
    return {
        c.name.removeprefix(conditions.CONDITION_PREFIX): c
        for c in conditions.check_conditions(
            segs,
            {**RECORDED_OK, **(recorded or {})},
            procedure=procedure,
            settings=settings or {},
            gravity=9.81,
            gravity_source=source,
        )
    }


def _status(check: CheckResult) -> str:
    return conditions.status(check)


@pytest.mark.parametrize(
    ("key", "inside", "outside"),
    [
        ("ambient_temperature_c", 22.0, 22.1),
        ("ambient_temperature_c", 18.0, 17.9),
        ("temperature_drift_c_per_h", 0.5, 0.6),
        ("humidity_pct", 60.0, 60.5),
        ("humidity_pct", 40.0, 39.5),
        ("warmup_min", 10.0, 9.0),
    ],
)
def test_environment_limits_are_warnings(key, inside, outside):
    segs = [_static("x_up")]
    ok = _checks(segs, {key: inside})[key]
    bad = _checks(segs, {key: outside})[key]
    assert ok.passed and _status(ok) == "pass"
    assert not bad.passed and _status(bad) == conditions.WARNING
    # a warning is reported, the verdict stands
    assert overall_verdict([bad]) == "pass"


@pytest.mark.parametrize(
    ("key", "inside", "outside"),
    [("resolution_bits", 16.0, 12.0), ("settle_s", 30.0, 29.0)],
)
def test_recorded_acquisition_limits_are_failures(key, inside, outside):
    segs = [_static("x_up")]
    assert _checks(segs, {key: inside})[key].passed
    bad = _checks(segs, {key: outside})[key]
    assert _status(bad) == "fail" and overall_verdict([bad]) == "fail"


def test_sampling_and_record_time_from_the_data():
    at_limit = _checks([_static("x_up", 10.0, 100.0)])
    assert at_limit["sample_rate_hz"].value == pytest.approx(100.0)
    assert at_limit["sample_rate_hz"].passed and at_limit["record_s"].passed
    slow = _checks([_static("x_up", 20.0, 99.0)])["sample_rate_hz"]
    short = _checks([_static("x_up", 9.9, 100.0), _static("x_dn")])["record_s"]
    assert _status(slow) == "fail" and "x_up" in slow.detail
    assert _status(short) == "fail" and short.value == pytest.approx(9.9) and "x_up" in short.detail
    # a rotation of the integral method is not an attitude: its length is not a record time
    assert _checks([_static("x_up"), _static("x_ccw", 5.0)])["record_s"].passed


def test_static_temperature_spread():
    # a linear ramp over 20 s; the 1-s means span (ramp - one second's worth)
    def ramp(total):
        return lambda t: 25.0 + total * t / 20.0

    # the rule of the static-bias run: without a chamber channel, the sensor's temperature
    ok = _checks([_static("x_up", temp=ramp(0.2))], procedure="static_bias")[
        "static_temperature_spread_c"
    ]
    bad = _checks(
        [_static("x_up", temp=ramp(0.25)), _static("x_dn", temp=ramp(0.0))], procedure="static_bias"
    )["static_temperature_spread_c"]
    assert ok.passed and ok.value < 0.2
    assert _status(bad) == "fail" and 0.2 < bad.value <= 0.25
    none = _checks([_static("x_up")], procedure="static_bias")["static_temperature_spread_c"]
    assert _status(none) == conditions.NOT_RECORDED


def test_static_bias_rule_judges_the_chamber_not_the_sensor():
    """The 0.2 deg C spread is the static-bias run's chamber (ambient) temperature: its
    reference channel when recorded; a warming sensor fails no other procedure."""

    def ramp(total):
        return lambda t: 25.0 + total * t / 20.0

    def with_chamber(rec: Recording, total: float) -> Recording:
        return replace(rec, reference={"chamber_temperature": ramp(total)(rec.t)})

    warming = _static("x_up", temp=ramp(1.0))  # the sensor warms by 1 deg C
    steady = _checks([with_chamber(warming, 0.1)], procedure="static_bias")
    drifting = _checks([with_chamber(warming, 0.3)], procedure="static_bias")
    assert steady["static_temperature_spread_c"].passed
    assert "chamber_temperature" in steady["static_temperature_spread_c"].detail
    bad = drifting["static_temperature_spread_c"]
    assert _status(bad) == "fail" and 0.2 < bad.value <= 0.3
    assert overall_verdict([bad]) == "fail"
    # other procedures: no spread rule; the sensor's trend is information, never a failure
    for procedure in ("six_position", "six_position_integral", "multi_position"):
        checks = _checks([warming], procedure=procedure)
        assert "static_temperature_spread_c" not in checks
        info = checks["sensor_temperature_spread_c"]
        assert 0.9 < info.value <= 1.0 and _status(info) == conditions.INFO
        assert overall_verdict(list(checks.values())) == "pass"


def test_table_rate_stability_and_deviation_per_plateau():
    settings = {"settle_s": 20.0}
    good = [_plateau("z_+100", 100.0, 0.09), _plateau("z_-100", -100.0, 0.05, 0.45)]
    checks = _checks(good, procedure="rate_table", settings=settings)
    assert checks["table_rate_stability_dps"].passed and checks["table_rate_deviation_dps"].passed
    assert checks["settle_rate_s"].passed and checks["record_s"].value == pytest.approx(10.0)
    unstable = _checks(
        [_plateau("z_+100", 100.0, 0.12)], procedure="rate_table", settings=settings
    )["table_rate_stability_dps"]
    off = _checks([_plateau("z_+50", 50.0, 0.01, 0.55)], procedure="rate_table", settings=settings)[
        "table_rate_deviation_dps"
    ]
    assert _status(unstable) == "fail" and "z_+100" in unstable.detail
    assert _status(off) == "fail" and off.value == pytest.approx(0.55, abs=1e-3)
    short_settle = _checks(good, procedure="rate_table", settings={"settle_s": 15.0})
    assert _status(short_settle["settle_rate_s"]) == "fail"


def test_a_settle_is_judged_only_where_the_solver_drops_one():
    """A rate table drops its settle_s (declared default 20 s) from each plateau: judged, and
    the record is what follows it. A centrifuge's solver drops none: no settle rule, each
    step's record is whole (30 s here, not 30 - 20)."""
    plateaus = [_plateau("z_+100", 100.0, 0.01), _plateau("z_-100", -100.0, 0.01)]
    table = _checks(plateaus, procedure="rate_table")
    assert table["settle_rate_s"].value == 20.0 and table["settle_rate_s"].passed
    assert table["record_s"].value == pytest.approx(10.0)
    steps = [_plateau("xp_step_10g", 200.0, 0.01), _plateau("xp_step_20g", 280.0, 0.01)]
    centrifuge = _checks(steps, procedure="centrifuge", settings={"latitude_deg": 50.0})
    assert "settle_rate_s" not in centrifuge
    assert centrifuge["record_s"].value == pytest.approx(30.0) and centrifuge["record_s"].passed
    assert centrifuge["table_rate_stability_dps"].passed


def test_not_recorded_is_no_pass_and_no_failure():
    checks = _checks([_static("x_up")], {k: None for k in RECORDED_OK}, source=None)
    for key in (
        "ambient_temperature_c",
        "humidity_pct",
        "pressure_hpa",
        "warmup_min",
        "settle_s",
        "resolution_bits",
        "temperature_drift_c_per_h",
    ):
        assert not checks[key].passed and _status(checks[key]) == conditions.NOT_RECORDED
    assert _status(checks["gravity"]) == conditions.WARNING
    assert overall_verdict(list(checks.values())) == "pass"
    failing = [*checks.values(), CheckResult("param:acc.bias.x", 1.0, 0.5, False)]
    assert overall_verdict(failing) == "fail"


def test_profile_sets_the_limits_and_refuses_unknown_ones():
    doc = {
        "name": "p",
        "version": "1",
        "device_model": "M",
        "conditions": {"sample_rate_hz": {"low": 45.0}},
    }
    profile = ToleranceProfile.from_dict(doc)
    check = conditions.check_conditions(
        {"x_up": _static("x_up", 20.0, 50.0)},
        RECORDED_OK,
        procedure="six_position",
        settings={},
        gravity=9.81,
        gravity_source="site",
        overrides=profile.conditions,
    )
    assert next(c for c in check if c.name.endswith("sample_rate_hz")).passed
    assert ToleranceProfile.from_dict(profile.to_dict()).conditions == profile.conditions
    with pytest.raises(ValueError, match="conditions.humidity: unknown condition"):
        ToleranceProfile.from_dict({**doc, "conditions": {"humidity": {"low": 1}}})
    with pytest.raises(ValueError, match=r"conditions.humidity_pct.low: expected a number"):
        ToleranceProfile.from_dict({**doc, "conditions": {"humidity_pct": {"low": "40"}}})
    shipped = tomllib.loads(
        (Path(__file__).parent.parent / "pipelines/profiles/mpu6000.toml").read_text()
    )
    assert shipped["conditions"]["sample_rate_hz"] == {"low": 45.0}  # the program's ~50 Hz


@pytest.mark.slow
def test_demo_certificates_show_the_conditions(tmp_path):
    """`make demo`: the sample runs' certificates and protocols carry the conditions (the
    CSV run records them, the MPU-6000 folder does not)."""
    arch = resolve_archive(str(tmp_path / "archive"))
    arch.upgrade()
    texts = {}
    folders = [DATA_SAMPLES / "csv_IMU-2026-0042", DATA_SAMPLES / "mpu6000_MPU0001"]
    for source in discover_runs(folders):
        outcome = process_run(source, arch)
        assert outcome["status"] == "ok", outcome["error"]
        status = {c["name"]: c["status"] for c in outcome["checks"]}
        texts[outcome["serial"]] = status
        args = [
            "report",
            outcome["run_id"],
            "--archive",
            str(arch.root),
            "--output",
            str(tmp_path / outcome["serial"]),
            "--json",
            "--no-pdf",
        ]
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 0, result.output
        html = next((tmp_path / outcome["serial"]).glob("*_certificate.html")).read_text()
        protocol = next((tmp_path / outcome["serial"]).glob("*_result.txt")).read_text()
        assert "<h2>Conditions</h2>" in html and "\nConditions\n" in protocol
        texts[outcome["serial"] + " html"] = html
    csv = texts["IMU-2026-0042"]
    # the CSV sample records its conditions (sample values in its run.toml): all judged
    assert csv["condition:ambient_temperature_c"] == "pass" and csv["condition:gravity"] == "pass"
    assert csv["condition:settle_s"] == "pass" and csv["condition:sample_rate_hz"] == "pass"
    assert "not recorded" not in csv.values()
    mpu = texts["MPU0001"]  # MPU-6000 files without a manifest record no environment
    assert mpu["condition:ambient_temperature_c"] == conditions.NOT_RECORDED
    assert mpu["condition:gravity"] == conditions.WARNING
    assert (
        "ambient temperature" in texts["MPU0001 html"] and "not recorded" in texts["MPU0001 html"]
    )


def _held(label: str, minutes: float, drift_arcsec: float, channel: str = "table_angle"):
    """A static record on the table at 100 Hz whose position feedback drifts linearly by
    `drift_arcsec` over the record, with 1 arcsec of encoder noise per sample."""
    rec = _static(label, 60.0 * minutes, 100.0)
    noise = np.random.default_rng(7).standard_normal(len(rec))
    angle = (0.5 + drift_arcsec * rec.t / rec.t[-1] + noise) * conditions.ARCSEC
    return Recording(t=rec.t, acc=rec.acc, gyr=rec.gyr, reference={channel: angle}, label=label)


def test_table_position_within_5_arcsec_during_the_static_run():
    """The rate-table procedure: table position deviation <= 5 arcsec during settling and
    the 60-min static run, from the table's feedback. 10 arcsec of drift fails, 3 passes;
    no feedback channel is "not recorded"; a two-axis table's pitch is read as well."""
    drifting = _checks([_held("z_up", 60.0, 10.0)], procedure="static_bias")
    bad = drifting["table_position_arcsec"]
    assert _status(bad) == "fail" and 9.0 < bad.value < 11.0 and bad.limit == 5.0
    assert "table_angle" in bad.detail and overall_verdict([bad]) == "fail"
    steady = _checks([_held("z_up", 60.0, 3.0)], procedure="static_bias")
    good = steady["table_position_arcsec"]
    assert _status(good) == "pass" and 2.0 < good.value < 4.0
    bare = _checks([_static("z_up", 600.0)], procedure="static_bias")["table_position_arcsec"]
    assert _status(bare) == conditions.NOT_RECORDED and "table_angle" in bare.detail
    pitch = _checks([_held("p1", 1.0, 10.0, "table_pitch")], procedure="multi_position")
    assert _status(pitch["table_position_arcsec"]) == "fail"
    # a rate-table run: its zero-rate plateau is held, the moving ones are not judged
    zero = _held("z_0", 1.0, 10.0)
    zero.reference["table_rate"] = np.zeros(len(zero))
    moving = _plateau("z_+50", 50.0, 0.01)
    moving.reference["table_angle"] = 50.0 * DEG * moving.t
    checks = _checks([zero, moving], procedure="rate_table", settings={"settle_s": 20.0})
    assert _status(checks["table_position_arcsec"]) == "fail"
    assert "z_0" in checks["table_position_arcsec"].detail
    zero.reference["table_angle"] = np.zeros(len(zero))
    checks = _checks([zero, moving], procedure="rate_table", settings={"settle_s": 20.0})
    assert _status(checks["table_position_arcsec"]) == "pass"
    # procedures off the table do not judge it
    assert "table_position_arcsec" not in _checks([_held("x_up", 1.0, 10.0)])


def test_the_static_bias_record_is_at_least_60_minutes():
    """docs/methods.md 2.5: >= 60 min; 59 min fails, 60 passes."""
    short = _checks([_static("z_up", 59.0 * 60.0)], procedure="static_bias")
    assert _status(short["static_record_min"]) == "fail"
    assert short["static_record_min"].value == pytest.approx(59.0)
    full = _checks([_static("z_up", 60.0 * 60.0)], procedure="static_bias")
    assert _status(full["static_record_min"]) == "pass"


def test_equipment_precheck_from_the_lab_file(tmp_path, monkeypatch):
    """The rate-table procedure's equipment pre-check (table angle accuracy, axis
    perpendicularity, power stability, IMU-to-table parallelism) from the lab file's
    equipment records: judged against the equipment's own limit (a profile's wins), "not
    recorded" where the lab gives none; a malformed record is refused by field."""
    from pipelines.lab import lab_precheck

    monkeypatch.setenv("CALIB_PROFILES", str(tmp_path))
    assert lab_precheck() == ({}, {})  # no lab file: nothing recorded
    (tmp_path / "lab.toml").write_text(
        '[[equipment]]\nserial = "RT-2"\ncertificate = "C-1"\n'
        "[equipment.precheck]\n"
        "table_angle_accuracy_arcsec = { value = 1.5, limit = 3.0 }\n"
        "table_axis_perpendicularity_arcsec = { value = 6.0, limit = 5.0 }\n"
        "power_stability_pct = { value = 0.2 }\n"
    )
    values, limits = lab_precheck()
    assert values == {
        "table_angle_accuracy_arcsec": 1.5,
        "table_axis_perpendicularity_arcsec": 6.0,
        "power_stability_pct": 0.2,
    }

    def judged(overrides):
        checks = conditions.check_conditions(
            {"z_up": _static("z_up", 60.0)},
            {**RECORDED_OK, **values},
            procedure="static_bias",
            settings={},
            gravity=9.81,
            gravity_source="site",
            overrides=overrides,
        )
        return {c.name.removeprefix(conditions.CONDITION_PREFIX): _status(c) for c in checks}

    status = judged(limits)
    assert status["table_angle_accuracy_arcsec"] == "pass"
    assert status["table_axis_perpendicularity_arcsec"] == "fail"
    assert status["power_stability_pct"] == "pass"  # no limit given: recorded
    assert status["imu_table_parallelism_arcsec"] == conditions.NOT_RECORDED
    assert judged({**limits, "power_stability_pct": {"high": 0.1}})["power_stability_pct"] == (
        "fail"
    )
    assert "table_angle_accuracy_arcsec" not in _checks([_static("x_up")])  # off the table
    (tmp_path / "lab.toml").write_text(
        '[[equipment]]\nserial = "RT-2"\ncertificate = "C-1"\n'
        '[equipment.precheck]\ntable_angle_accuracy_arcsec = { value = "1" }\n'
    )
    # as a manifest's and a tolerance profile's errors: file, the line of the key, the field
    with pytest.raises(
        ValueError,
        match=r"lab.toml line 5: equipment\[0\]\.precheck\.table_angle_accuracy_arcsec\.value: ",
    ):
        lab_precheck()
    (tmp_path / "lab.toml").write_text(
        '[[equipment]]\nserial = "RT-2"\ncertificate = "C-1"\n'
        "[equipment.precheck]\ntable_flatness = { value = 1 }\n"
    )
    with pytest.raises(
        ValueError,
        match=r"lab.toml line 5: equipment\[0\]\.precheck\.table_flatness: unknown pre-check "
        r"item of .*; expected one of imu_table_parallelism_arcsec, power_stability_pct, ",
    ):
        lab_precheck()
