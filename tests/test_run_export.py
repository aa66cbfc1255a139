"""`calib export RUN --format px4|ardupilot|json|csv|mat` (docs/exports.md).

Golden files (tests/golden/) are written by hand from PX4's and ArduPilot's own
sources (names, units, signs) for a known calibration; the exported files are
then read back and applied with the firmware's formula, which must give the
calibration's own corrected output. Tolerances: values are written with 9
significant digits (relative rounding <= 5e-9 each), so a corrected sample can
differ by at most ~1e-8 of the raw magnitude; the bounds below are 10x that.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.io import loadmat
from serve_sample import THERMAL_SERIAL
from typer.testing import CliRunner

from calib_core import params
from calib_core.calibration import Calibration
from calib_core.thermal import ParameterCurve, ThermalModel
from calib_testing.golden import golden_calibration
from pipelines import exports
from pipelines.cli import app
from pipelines.run_export import export_run
from storage import queries

GOLDEN = Path(__file__).parent / "golden"
ACC_ID, GYRO_ID = 1310988, 2359308
REL = 1e-7  # 10x the 9-digit rounding (see the module docstring)


def _param_lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]


def test_px4_golden_file():
    rows, notes = exports.px4_calibration_parameters(
        golden_calibration(), accel_id=ACC_ID, gyro_id=GYRO_ID
    )
    text = exports.px4_params_text(rows, header="\n".join(notes))
    golden = (GOLDEN / "px4_calibration.params").read_text()
    assert sorted(_param_lines(text)) == sorted(_param_lines(golden))
    assert len(notes) == 4  # acc.misalign, gyr.noise, gyr.scale; never silently dropped; TC off
    assert "TC_A_ENABLE and TC_G_ENABLE set to 0" in notes[-1]
    for family in ("acc.misalign", "gyr.scale", "gyr.noise"):
        assert any(family in n for n in notes) and f"{family} [" in text
    assert "acc.misalign [1]: xy 0.002" in text and "gyr.scale [1]: x 0.005" in text
    assert "xy 0.002 (up to 0.2 % of the input left uncorrected)" in text
    assert "x 0.005 (up to 0.5 % of the input left uncorrected)" in text
    assert "device id 0" not in text


def test_ardupilot_golden_file():
    rows, notes = exports.ardupilot_calibration_parameters(golden_calibration())
    text = exports.ardupilot_params_text(rows, header="\n".join(notes))
    golden = (GOLDEN / "ardupilot_calibration.param").read_text()
    assert sorted(_param_lines(text)) == sorted(_param_lines(golden))
    assert "acc.misalign [1]: xy 0.002" in text and "no ArduPilot parameter" in text
    assert "INS_ACC1_CALTEMP / INS_GYR1_CALTEMP not written" in notes[-1]
    at = dict(exports.ardupilot_calibration_parameters(golden_calibration(), cal_temp=21.5)[0])
    assert at["INS_ACC1_CALTEMP"] == at["INS_GYR1_CALTEMP"] == 21.5  # as ArduPilot's accel cal
    second = dict(exports.ardupilot_calibration_parameters(golden_calibration(), imu=2)[0])
    assert {"INS_ACC2OFFS_X", "INS_GYR2OFFS_Z", "INS_ACC2SCAL_Y"} <= set(second)
    with pytest.raises(ValueError, match="IMU 4"):
        exports.ardupilot_calibration_parameters(golden_calibration(), imu=4)


def test_scale_outside_the_firmware_range_is_refused():
    cal = golden_calibration()
    cal.add("acc.scale.y", -0.3)  # ArduPilot scale 1/0.7 = 1.43 > 1.2
    with pytest.raises(ValueError, match=r"acc\.scale\.y .*ArduPilot.*0\.8 \.\. 1\.2"):
        exports.ardupilot_calibration_parameters(cal)


# --- round trip: the firmware's formula on real samples ---------------------


def _mapped_only(cal: Calibration) -> Calibration:
    """The calibration reduced to what both firmwares carry: biases and accelerometer scales."""
    keep = [params.bias(s, a) for s in ("acc", "gyr") for a in params.AXES]
    keep += [f"acc.scale.{a}" for a in params.AXES]
    out = Calibration(cal.procedure, cal.gravity)
    for n in keep:
        out.add(n, cal.value(n))
    return out


def _raw(archive, run_id) -> tuple[np.ndarray, np.ndarray]:
    t = queries.run_samples(archive, run_id).to_pandas()
    return t[["acc_x", "acc_y", "acc_z"]].to_numpy(), t[["gyr_x", "gyr_y", "gyr_z"]].to_numpy()


@pytest.mark.parametrize("fmt", ["px4", "ardupilot"])
def test_firmware_formula_reproduces_the_calibration(archived_sample, tmp_path, fmt):
    archive, run_id = archived_sample
    result = export_run(archive, run_id, fmt, accel_id=ACC_ID, gyro_id=GYRO_ID)
    path = tmp_path / f"out.{fmt}"
    path.write_bytes(result.data)
    cal = Calibration.from_dict(queries.export_calibration(archive, run_id)["calibration"])
    acc, gyr = _raw(archive, run_id)
    if fmt == "px4":  # Accelerometer.hpp / Gyroscope.hpp Correct(), sensor frame
        p = exports.read_px4_params(path)
        off_a = np.array([p[f"CAL_ACC0_{a}OFF"] for a in "XYZ"])
        scl = np.array([p[f"CAL_ACC0_{a}SCALE"] for a in "XYZ"])
        off_g = np.array([p[f"CAL_GYRO0_{a}OFF"] for a in "XYZ"])
    else:  # AP_InertialSensor_Backend::_rotate_and_correct_accel / _gyro
        p = exports.read_ardupilot_params(path)
        off_a = np.array([p[f"INS_ACCOFFS_{a}"] for a in "XYZ"])
        scl = np.array([p[f"INS_ACCSCAL_{a}"] for a in "XYZ"])
        off_g = np.array([p[f"INS_GYROFFS_{a}"] for a in "XYZ"])
    acc_fw, gyr_fw = (acc - off_a) * scl, gyr - off_g
    want_acc, want_gyr = _mapped_only(cal).correct(acc, gyr)
    np.testing.assert_allclose(acc_fw, want_acc, rtol=0, atol=REL * np.abs(acc).max())
    np.testing.assert_allclose(gyr_fw, want_gyr, rtol=0, atol=REL * np.abs(gyr).max())
    # What the file cannot carry matters on this unit (misalignment ~1e-2, gyro scale ~3e-2),
    # and each such family is in the warnings and the file's header.
    full_acc, _ = cal.correct(acc, gyr)
    assert np.abs(full_acc - acc_fw).max() > 1e3 * REL * np.abs(acc).max()
    text = result.data.decode()
    for family in ("acc.misalign", "gyr.misalign", "gyr.scale", "gyr.gsens"):
        assert any(family in w for w in result.warnings)
        assert (
            f"# WARNING: not exported (no {'PX4' if fmt == 'px4' else 'ArduPilot'} "
            f"parameter): {family}" in text
        )


COEF = {  # SI per deg C^k around T_ref = 25 (as tests/test_exports.py)
    "acc.bias.x": [0.12, 3e-3, -4e-5, 6e-7],
    "acc.bias.y": [-0.05, -2e-3, 1e-5],
    "gyr.bias.x": [0.01, 2e-4, -3e-6, 4e-8],
    "gyr.bias.z": [-0.02, -1e-4],
}
TEMPS = np.array([-25.0, -10.0, 0.0, 17.3, 35.0, 59.9, 80.0])  # both clip sides


def _model() -> ThermalModel:
    curves = {
        n: ParameterCurve(n, np.array(c), np.eye(len(c)) * 1e-12, 1.0, 8) for n, c in COEF.items()
    }
    return ThermalModel(25.0, -10.0, 60.0, curves)


@pytest.mark.parametrize("cal_temp", [21.5, None])
def test_thermal_terms_reproduce_calib_apply(cal_temp):
    """PX4 TC_* + CAL_* and ArduPilot INS_TCAL + INS_*OFFS reproduce ThermalModel.correct."""
    cal, model = _mapped_only(golden_calibration()), _model()
    rng = np.random.default_rng(7)
    acc = rng.normal(0, 9.8, (len(TEMPS), 3))
    gyr = rng.normal(0, 1.0, (len(TEMPS), 3))
    want_acc, want_gyr = model.correct(acc, gyr, TEMPS, cal, cal_temp)

    rows, notes = exports.px4_calibration_parameters(
        cal, accel_id=ACC_ID, gyro_id=GYRO_ID, model=model, cal_temp=cal_temp
    )
    p = {n: v for n, v, _ in rows}
    assert all(p[f"CAL_{s}0_{a}OFF"] == 0 for s in ("ACC", "GYRO") for a in "XYZ")

    def tc(s: str) -> np.ndarray:  # TemperatureCompensation::calc_thermal_offsets_3D
        dT = np.clip(TEMPS, p[f"TC_{s}0_TMIN"], p[f"TC_{s}0_TMAX"]) - p[f"TC_{s}0_TREF"]
        return np.stack(
            [sum(p[f"TC_{s}0_X{k}_{i}"] * dT**k for k in range(4)) for i in range(3)], 1
        )

    scl = np.array([p[f"CAL_ACC0_{a}SCALE"] for a in "XYZ"])
    np.testing.assert_allclose((acc - tc("A")) * scl, want_acc, rtol=0, atol=REL * 30)
    np.testing.assert_allclose(gyr - tc("G"), want_gyr, rtol=0, atol=REL * 3)
    assert ("calibration temperature unknown" in " ".join(notes)) == (cal_temp is None)

    rows, _ = exports.ardupilot_calibration_parameters(cal, model=model, cal_temp=cal_temp)
    q = dict(rows)
    assert q["INS_ACC1_CALTEMP"] == q["INS_GYR1_CALTEMP"] == (cal_temp or model.t_ref)
    if cal_temp is not None:  # ArduPilot's offsets are its calibration's, taken at CALTEMP
        for a in params.AXES:
            assert q[f"INS_ACCOFFS_{a.upper()}"] == pytest.approx(cal.value(f"acc.bias.{a}"))
            assert q[f"INS_GYROFFS_{a.upper()}"] == pytest.approx(cal.value(f"gyr.bias.{a}"))

    def poly(tag: str, T: np.ndarray) -> np.ndarray:  # AP_InertialSensor_TCal, x 1e-6
        T = np.clip(T, q["INS_TCAL1_TMIN"], q["INS_TCAL1_TMAX"]) - 35.0
        c = [[q[f"INS_TCAL1_{tag}{k}_{a}"] for a in "XYZ"] for k in (1, 2, 3)]
        T = T[:, None]
        return (np.array(c[0]) + (np.array(c[1]) + np.array(c[2]) * T) * T) * T * 1e-6

    t_cal = np.full(len(TEMPS), q["INS_ACC1_CALTEMP"])
    off_a = np.array([q[f"INS_ACCOFFS_{a}"] for a in "XYZ"])
    off_g = np.array([q[f"INS_GYROFFS_{a}"] for a in "XYZ"])
    scl = np.array([q[f"INS_ACCSCAL_{a}"] for a in "XYZ"])
    acc_ap = (acc - poly("ACC", TEMPS) + poly("ACC", t_cal) - off_a) * scl
    gyr_ap = gyr - poly("GYR", TEMPS) + poly("GYR", t_cal) - off_g
    np.testing.assert_allclose(acc_ap, want_acc, rtol=0, atol=REL * 30)
    np.testing.assert_allclose(gyr_ap, want_gyr, rtol=0, atol=REL * 3)


def test_non_bias_thermal_curves_are_reported():
    model = _model()
    model.curves["acc.scale.x"] = ParameterCurve(
        "acc.scale.x", np.array([0.01, 1e-4]), np.eye(2) * 1e-12, 1.0, 8
    )
    for build in (exports.px4_calibration_parameters, exports.ardupilot_calibration_parameters):
        _, notes = build(golden_calibration(), model=model, cal_temp=20.0)
        assert any("thermal curves of acc.scale.x" in n for n in notes), notes


# --- csv and mat --------------------------------------------------------------


def test_csv_and_mat_carry_every_parameter(archived_sample, tmp_path):
    archive, run_id = archived_sample
    doc = queries.export_calibration(archive, run_id)
    cal = Calibration.from_dict(doc["calibration"])
    df = pd.read_csv(io.BytesIO(export_run(archive, run_id, "csv").data))
    assert list(df.columns) == ["name", "value", "std", "unit"]
    assert list(df["name"]) == sorted(cal.parameters)
    for row in df.itertuples():
        p = cal.parameters[row.name]
        assert row.value == p.value and row.unit == p.unit
        assert np.isnan(row.std) if p.std is None else row.std == p.std

    path = tmp_path / "cal.mat"
    path.write_bytes(export_run(archive, run_id, "mat").data)
    m = loadmat(path)
    names = [str(c[0]) for c in m["parameter_names"][:, 0]]
    assert names == sorted(cal.parameters)
    np.testing.assert_array_equal(m["parameter_values"][:, 0], [cal.value(n) for n in names])
    np.testing.assert_array_equal(m["acc_M"], cal.matrix("acc"))
    np.testing.assert_array_equal(m["gyr_G"], cal.gsens())
    np.testing.assert_array_equal(m["acc_bias"][:, 0], cal.vector("acc", "bias"))
    np.testing.assert_array_equal(m["covariance"], cal.covariance)
    i = names.index("acc.bias.x")
    k = int(m["parameter_cov_index"][i, 0])  # 1-based, as MATLAB indexes
    assert np.sqrt(m["covariance"][k - 1, k - 1]) == pytest.approx(cal.parameters[names[i]].std)
    assert str(m["run_id"][0]) == run_id and str(m["serial"][0]) == doc["unit"]["serial"]
    assert "thermal_coef" not in m  # this unit has no thermal model


# --- the command, on an archive with a thermal model ------------------------


def _invoke(*args: str):
    return CliRunner().invoke(app, ["export", *args])


@pytest.mark.slow
def test_cli_exports_with_the_thermal_model(serve_sample, tmp_path):
    root = str(serve_sample.archive.root)
    run_id = serve_sample.runs[THERMAL_SERIAL][2]  # the 20 deg C point of the campaign
    temp = queries.run_summary(serve_sample.archive, run_id).temperature_c
    out = tmp_path / "th.params"
    res = _invoke(
        run_id[:8],
        "--archive",
        root,
        "--format",
        "px4",
        "-o",
        str(out),
        "--accel-id",
        str(ACC_ID),
        "--gyro-id",
        str(GYRO_ID),
    )
    assert res.exit_code == 0, res.output
    assert "warning: not exported" in res.stderr and f"wrote {out}" in res.stderr
    p = exports.read_px4_params(out)
    assert p["TC_A_ENABLE"] == 1 and p["TC_A0_ID"] == ACC_ID and p["CAL_GYRO0_ID"] == GYRO_ID
    assert p["CAL_ACC0_XOFF"] == 0.0  # the bias is in TC_A0_X0..X3
    res = _invoke(run_id, "--archive", root, "--format", "px4", "--no-thermal")
    assert res.exit_code == 2 and "give --device-id" in " ".join(res.stderr.split())
    res = _invoke(run_id, "--archive", root, "--format", "px4", "--no-thermal", "--device-id", "9")
    assert res.exit_code == 0 and "TC_A0_X0_0" not in res.stdout
    assert "TC_A_ENABLE\t0" in res.stdout and "CAL_ACC0_ID\t9" in res.stdout

    res = _invoke(run_id, "--archive", root, "--format", "ardupilot", "--instance", "2")
    q = exports.read_ardupilot_params(_write(tmp_path / "ap.param", res.stdout))
    assert q["INS_ACC2_CALTEMP"] == temp and q["INS_TCAL2_ENABLE"] == 1 and "INS_ACC2OFFS_X" in q

    res = _invoke(run_id, "--archive", root, "--format", "csv")
    df = pd.read_csv(io.StringIO(res.stdout))
    assert {"thermal:t_ref", "thermal:acc.bias.x:c0"} <= set(df["name"])

    path = tmp_path / "th.mat"
    assert _invoke(run_id, "--archive", root, "--format", "mat", "-o", str(path)).exit_code == 0
    m = loadmat(path)
    model = queries.latest_thermal_model(serve_sample.archive, THERMAL_SERIAL)
    assert m["thermal_coef"].shape[0] == len(model["document"]["curves"])
    assert m["calibration_temperature_c"][0, 0] == temp

    doc = json.loads(_invoke(run_id, "--archive", root).stdout)  # json: the archive document
    assert doc == json.loads(
        json.dumps(queries.export_calibration(serve_sample.archive, run_id), default=str)
    )


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_cli_refuses_unknown_formats_and_mat_to_a_terminal(archived_sample):
    archive, run_id = archived_sample
    res = _invoke(run_id, "--archive", str(archive.root), "--format", "px5")
    assert res.exit_code == 2 and "json, px4, ardupilot, csv, mat" in " ".join(res.stderr.split())
    res = _invoke(run_id, "--archive", str(archive.root), "--format", "mat")
    assert res.exit_code == 2 and "--output" in res.stderr
