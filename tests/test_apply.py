"""A thermal campaign through the real flow and archive, then `calib apply` at a new temperature.

The unit has polynomial thermal truth. Its runs at 8 temperature points are
written as CSV runs with manifests, processed and fitted by the Prefect
`thermal_campaign` flow; new raw data at 35 deg C (no campaign point there) are
calibrated by `calib apply` and compared with the true specific force and rate.
"""

from __future__ import annotations

import json
import re
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from calib_core import params
from calib_core.calibration import Calibration
from calib_core.simulate.lab_run import rotation_profile, six_position_integral_run
from calib_core.simulate.thermal import random_thermal_truth, thermal_campaign
from calib_core.solvers.six_position import axis_vector
from calib_core.thermal import ThermalModel
from calib_core.units import DEG, STANDARD_GRAVITY
from calib_testing.archives import parameter_run
from calib_testing.run_writers import write_csv_run, write_mpu6000_run
from pipelines import exports
from pipelines.cli import app
from storage import queries
from storage import thermal as thermal_store
from storage.archive import archive_run
from storage.db import resolve_archive
from storage.run_input import RunIn

SERIAL = "TH-0042"
TEMPS = (-10.0, 0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0)
START = datetime(2026, 3, 2, 8, 0, tzinfo=UTC)
UNTESTED_C = 35.0


def _manifest(temp: float, started: datetime) -> dict:
    return {
        "schema_version": 1,
        "unit": {"serial": SERIAL, "model": "MPU-6000", "manufacturer": "InvenSense"},
        "run": {
            "started": started.isoformat(),
            "operator": "test",
            "procedure": "six_position_integral",
            "tolerance_profile": "mpu6000",
        },
        "site": {"gravity_model": "standard"},
        "environment": {"temperature_c": temp},
    }


@pytest.fixture(scope="module")
def campaign(tmp_path_factory, prefect_harness):
    from pipelines.flows import thermal_campaign as flow

    root = tmp_path_factory.mktemp("thermal")
    rng = np.random.default_rng(2024)
    truth = random_thermal_truth(rng)
    for i, run in enumerate(thermal_campaign(truth, rng, TEMPS)):
        started = START + timedelta(days=i)
        write_csv_run(
            run.run.segments, root / "campaign" / f"run{i}", _manifest(run.temperature, started)
        )
    result = flow([str(root / "campaign")], str(root / "archive"))
    arch = resolve_archive(str(root / "archive"))
    return {"root": root, "truth": truth, "rng": rng, "result": result, "archive": arch}


def test_flow_processed_and_fitted_the_campaign(campaign):
    result = campaign["result"]
    assert [r["status"] for r in result["runs"]] == ["ok"] * len(TEMPS)
    fit = result["thermal"]
    assert (fit["t_min"], fit["t_max"], fit["t_ref"]) == (-10.0, 60.0, 25.0)
    assert fit["hysteresis"] == {}  # heating only: no hysteresis term
    assert len(fit["runs"]) == len(TEMPS)
    row = queries.latest_thermal_model(campaign["archive"], SERIAL)
    assert row["id"] == fit["model_id"] and len(row["calibration_ids"]) == len(TEMPS)


def test_thermal_fit_on_a_read_only_archive_says_nothing_was_written(campaign, monkeypatch):
    """The SQLite file opened read-only (a URI SQLite enforces, also for root)."""
    from sqlalchemy.engine import make_url

    arch = campaign["archive"]
    before = len(queries.thermal_models(arch, SERIAL))
    monkeypatch.setenv("CALIB_FILESTORE", str(arch.root))
    read_only = f"sqlite:///file:{make_url(arch.url).database}?mode=ro&uri=true"
    res = CliRunner().invoke(app, ["thermal", "fit", SERIAL, "--archive", read_only])
    assert res.exit_code == 2, res.output
    assert f"thermal model of {SERIAL} not written" in res.output and "read-only" in res.output
    assert len(queries.thermal_models(arch, SERIAL)) == before


def test_thermal_fit_command_refits_and_supersedes(campaign):
    arch = campaign["archive"]
    before = queries.latest_thermal_model(arch, SERIAL)["id"]
    res = CliRunner().invoke(app, ["thermal", "fit", SERIAL, "--archive", str(arch.root), "--json"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    models = queries.thermal_models(arch, SERIAL)
    assert summary["model_id"] > before
    assert models.set_index("id").loc[before, "superseded_by"] == summary["model_id"]
    # The benefit figures: the bias change over 70 deg C is many times the fit residual.
    b = summary["benefit"]["acc.bias.x"]
    assert b["rms_after"] * 10 < b["rms_before"]


def _new_data(campaign) -> tuple[Path, dict]:
    """Raw data of the unit at 35 deg C written as a CSV run; truth per segment."""
    truth, rng = campaign["truth"], campaign["rng"]
    sim = six_position_integral_run(truth.errors_at(UNTESTED_C), rng, temp_c=UNTESTED_C)
    folder = campaign["root"] / "new35"
    write_csv_run(sim.segments, folder, _manifest(UNTESTED_C, START + timedelta(days=40)))
    s = sim.settings
    _, rate = rotation_profile(s["rate_hz"], s["turns"], s["rotation_rate_dps"] * DEG, s["pause_s"])
    want = {}
    for label, rec in sim.segments.items():
        w = np.zeros((len(rec), 3))
        axis, sense = label.split("_")
        if sense in ("ccw", "cw"):
            w[:, params.AXIS_INDEX[axis]] = rate if sense == "ccw" else -rate
        want[label] = (np.broadcast_to(axis_vector(label, STANDARD_GRAVITY), (len(rec), 3)), w)
    return folder, {"want": want, "sim": sim}


def test_apply_round_trip_at_an_untested_temperature(campaign, tmp_path):
    """Calibrated output minus truth: RMS per channel <= 1.15 x the unit's white noise.

    Expected RMS^2 = noise^2 + (parameter error)^2, with parameter errors (~1e-4
    m/s^2, ~1e-5 rad/s) far below the noise (~1e-2, ~1e-3); the sampling scatter
    of an RMS over ~16000 samples is < 1 %, so 1.15 allows a systematic error of
    up to half the noise and no more. Without the thermal model (calibration at
    20 deg C alone) the accelerometer error exceeds 1.5 x noise on every axis:
    the test can tell the two apart.
    """
    arch = campaign["archive"]
    folder, t = _new_data(campaign)
    out = tmp_path / "calibrated.parquet"
    day = (START + timedelta(days=3)).date().isoformat()  # the 20 deg C run's day
    res = CliRunner().invoke(
        app,
        [
            "apply",
            str(folder),
            str(out),
            "--serial",
            SERIAL,
            "--at",
            day,
            "--archive",
            str(arch.root),
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    facts = json.loads(res.stdout)
    assert facts["calibration_temperature_c"] == 20.0 and facts["thermal_model_id"] is not None
    assert facts["samples_outside_thermal_range"] == 0
    df = pd.read_parquet(out)
    sim = t["sim"]
    assert len(df) == sum(len(r) for r in sim.segments.values())

    err_acc, err_gyr, raw_acc = [], [], []
    rows = queries.campaign_calibrations(arch, SERIAL)
    cal = Calibration.from_dict(next(r for r in rows if r["temperature_c"] == 20.0)["document"])
    for label, (f_true, w_true) in t["want"].items():
        seg = df[df["segment"] == label]
        acc = seg[[f"acc_{a}" for a in params.AXES]].to_numpy()
        gyr = seg[[f"gyr_{a}" for a in params.AXES]].to_numpy()
        err_acc.append(acc - f_true)
        err_gyr.append(gyr - w_true)
        plain, _ = cal.correct(sim.segments[label].acc, sim.segments[label].gyr)
        raw_acc.append(plain - f_true)
    rms = lambda e: np.sqrt(np.mean(np.concatenate(e) ** 2, axis=0))  # noqa: E731
    truth = campaign["truth"].base
    assert np.all(rms(err_acc) <= 1.15 * truth.acc_noise), rms(err_acc) / truth.acc_noise
    assert np.all(rms(err_gyr) <= 1.15 * truth.gyr_noise), rms(err_gyr) / truth.gyr_noise
    assert np.all(rms(raw_acc) > 1.5 * truth.acc_noise), rms(raw_acc) / truth.acc_noise


def _apply_args(source, out, campaign) -> list[str]:
    """`calib apply` of `source` into `out` with SERIAL's calibrations of the campaign."""
    return [
        "apply",
        str(source),
        str(out),
        "--serial",
        SERIAL,
        "--archive",
        str(campaign["archive"].root),
    ]


def test_apply_to_one_mpu6000_file_writes_csv(campaign, tmp_path):
    truth, rng = campaign["truth"], campaign["rng"]
    sim = six_position_integral_run(truth.errors_at(UNTESTED_C), rng, temp_c=UNTESTED_C)
    files = write_mpu6000_run({"z_up": sim.segments["z_up"]}, tmp_path / "mpu", SERIAL)
    out = tmp_path / "z_up.csv"
    res = CliRunner().invoke(app, _apply_args(files[0], out, campaign))
    assert res.exit_code == 0, res.output
    df = pd.read_csv(out)
    assert list(df.columns) == [
        "segment",
        "t",
        "acc_x",
        "acc_y",
        "acc_z",
        "gyr_x",
        "gyr_y",
        "gyr_z",
        "temp",
    ]
    # Mean of 1000 samples: within 5 standard errors of (0, 0, g) plus the file's
    # 0.00005 m/s^2 print rounding (MPU-6000 layout, 4 decimals).
    n = len(df)
    tol = 5 * truth.base.acc_noise / np.sqrt(n) + 5e-5
    mean = df[["acc_x", "acc_y", "acc_z"]].mean().to_numpy()
    assert np.all(np.abs(mean - [0, 0, STANDARD_GRAVITY]) < tol), (mean, tol)


def test_apply_prints_a_table_and_warns_of_another_serial(campaign, tmp_path):
    """Without --json: a table of what was applied (no JSON on stdout); data whose file
    names another serial than --serial is calibrated as asked, with a warning naming both."""
    truth, rng = campaign["truth"], campaign["rng"]
    sim = six_position_integral_run(truth.errors_at(UNTESTED_C), rng, temp_c=UNTESTED_C)
    files = write_mpu6000_run({"z_up": sim.segments["z_up"]}, tmp_path / "mpu", "OTHER-7")
    out = tmp_path / "z_up.csv"
    args = _apply_args(files[0], out, campaign)
    res = CliRunner().invoke(app, args, env={"COLUMNS": "80"})
    assert res.exit_code == 0, res.output
    assert not res.stdout.lstrip().startswith("{")
    assert re.search(r"│ serial\s+│ TH-0042", res.stdout) and "data serial" in res.stdout
    assert f"output: {out}\n" in res.stdout  # whole, on its own line
    assert "warning:" in res.stderr and "'OTHER-7'" in res.stderr and "'TH-0042'" in res.stderr
    res = CliRunner().invoke(app, [*args, "--json"])
    facts = json.loads(res.stdout)
    assert facts["data_serial"] == "OTHER-7" and len(facts["warnings"]) == 1
    files = write_mpu6000_run({"z_up": sim.segments["z_up"]}, tmp_path / "own", SERIAL)
    res = CliRunner().invoke(app, [*_apply_args(files[0], out, campaign), "--json"])
    assert res.exit_code == 0 and "warning" not in res.stderr
    assert json.loads(res.stdout)["warnings"] == []


def test_apply_errors_are_clear(campaign, tmp_path):
    arch = campaign["archive"]
    res = CliRunner().invoke(
        app,
        [
            "apply",
            str(tmp_path),
            str(tmp_path / "x.txt"),
            "--serial",
            SERIAL,
            "--archive",
            str(arch.root),
        ],
    )
    assert res.exit_code == 2 and "expected a .parquet, .pq or .csv" in res.output
    res = CliRunner().invoke(
        app,
        [
            "apply",
            str(tmp_path),
            str(tmp_path / "x.csv"),
            "--serial",
            SERIAL,
            "--at",
            "2020-01-01",
            "--archive",
            str(arch.root),
        ],
    )
    assert res.exit_code == 2 and "no valid (passed, current) calibration" in res.output


@pytest.mark.parametrize("fmt", ["json", "px4", "ardupilot"])
def test_thermal_export_command(campaign, tmp_path, fmt):
    arch = campaign["archive"]
    out = tmp_path / f"export.{fmt}"
    ids = ["--device-id", "1310988"] if fmt == "px4" else []  # its CSV runs record none
    res = CliRunner().invoke(
        app,
        ["thermal", "export", SERIAL, str(out), "--format", fmt, "--archive", str(arch.root), *ids],
    )
    assert res.exit_code == 0, res.output
    model = ThermalModel.from_dict(queries.latest_thermal_model(arch, SERIAL)["document"])
    if fmt == "json":
        doc = json.loads(out.read_text())
        assert ThermalModel.from_dict(doc["thermal_model"]).parameters_at(
            33.0
        ) == model.parameters_at(33.0)
        assert doc["unit"]["serial"] == SERIAL
    elif fmt == "px4":
        got = exports.read_px4_params(out)
        assert got["TC_G0_TREF"] == model.t_ref
        c = model.curves["gyr.bias.y"].coef
        assert got["TC_G0_X1_1"] == pytest.approx(c[1] if c.size > 1 else 0.0, rel=1e-7)
    else:
        got = exports.read_ardupilot_params(out)
        assert got["INS_TCAL1_TMIN"] == model.t_min and got["INS_TCAL1_ENABLE"] == 1


# --- storage of thermal models, both back ends ----------------------------------------------


def _minimal_run(tmp_path: Path, serial: str, k: int) -> RunIn:
    return parameter_run(
        tmp_path,
        serial,
        START + timedelta(days=k),
        temperature_c=10.0 * k,
        device_model="M",
        manufacturer="x",
        procedure="six_position",
        operator=None,
        gravity=9.8,
        profile_name=None,
        profile_version=None,
        software_version="t",
    )


def test_thermal_models_are_stored_and_superseded(archive, tmp_path):
    ids = [archive_run(archive, _minimal_run(tmp_path, "S1", k)).calibration_id for k in range(3)]
    other = archive_run(archive, _minimal_run(tmp_path, "S2", 0)).calibration_id
    doc = {
        "model": "polynomial",
        "schema_version": 1,
        "t_ref": 10.0,
        "t_min": 0.0,
        "t_max": 20.0,
        "curves": {},
    }
    first = thermal_store.archive_thermal_model(archive, "S1", doc, ids)
    second = thermal_store.archive_thermal_model(archive, "S1", {**doc, "t_ref": 11.0}, ids[:2])
    latest = queries.latest_thermal_model(archive, "S1")
    assert (
        latest["id"] == second and latest["t_ref"] == 11.0 and latest["calibration_ids"] == ids[:2]
    )
    rows = queries.thermal_models(archive, "S1").set_index("id")
    assert rows.loc[first, "superseded_by"] == second
    assert queries.latest_thermal_model(archive, "S2") is None
    with pytest.raises(ValueError, match=r"not calibrations of 'S1'"):
        thermal_store.archive_thermal_model(archive, "S1", doc, [ids[0], other])
    with pytest.raises(LookupError, match="no device with serial 'NOPE'"):
        thermal_store.archive_thermal_model(archive, "NOPE", doc, ids)
    camp = queries.campaign_calibrations(archive, "S1")
    assert [c["temperature_c"] for c in camp] == [0.0, 10.0, 20.0]
