"""Autopilot files that take effect (docs/exports.md): the device ids the firmware matches, the
IMU's mounting by the firmware's own rotation names, the vehicle id, the header.

The firmware's arithmetic is replayed on the written file, read back by the parser of that
file: PX4 rotates the sensor's axes (``Dcmf{Eulerf{roll, pitch, yaw}}`` of rot_lookup,
src/lib/conversion/rotation.cpp) and then corrects ``(data - thermal_offset - CAL_*_OFF) *
CAL_*_SCALE``; ArduPilot rotates (``Vector3::rotate``, libraries/AP_Math/vector3.cpp,
transcribed below) and then subtracts its temperature correction and INS_ACCOFFS and
multiplies by INS_ACCSCAL. The unit's raw output is (I + S) f + b in its calibrated axes; the
firmware must give R f. Values are written with 9 significant digits: REL as in
tests/test_run_export.py.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from log_writers import write_dataflash, write_ulog
from typer.testing import CliRunner

from calib_core.calibration import Calibration
from calib_core.simulate import random_errors, six_position_integral_run
from calib_core.simulate.thermal import random_thermal_truth, thermal_campaign
from calib_core.thermal import ParameterCurve, ThermalModel
from calib_core.units import DEG
from calib_testing.golden import firmware_calibration
from calib_testing.run_writers import dumps_toml, six_position_manifest
from pipelines import autopilot, exports
from pipelines.cli import app
from pipelines.ingest import discover_runs
from pipelines.process import process_run
from storage.db import resolve_archive

REL = 1e-7
ACC_ID, GYRO_ID = 1310988, 2359308
H = 0.70710678118654757  # ArduPilot's HALF_SQRT_2


def _px4_dcm(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """PX4 matrix::Dcm<float>(Euler): its nine direction cosines as written there."""
    phi, the, psi = (math.radians(a) for a in (roll, pitch, yaw))
    cp, sp, ct, st, cs, ss = (
        math.cos(phi),
        math.sin(phi),
        math.cos(the),
        math.sin(the),
        math.cos(psi),
        math.sin(psi),
    )
    return np.array(
        [
            [ct * cs, -cp * ss + sp * st * cs, sp * ss + cp * st * cs],
            [ct * ss, cp * cs + sp * st * ss, -sp * cs + cp * st * ss],
            [-st, sp * ct, cp * ct],
        ]
    )


def _ap_rotate(name: str, v: np.ndarray) -> np.ndarray:
    """ArduPilot's Vector3<T>::rotate for the cases the tests use, line by line."""
    x, y, z = v[..., 0].copy(), v[..., 1].copy(), v[..., 2].copy()
    if name == "YAW_45":
        tmp = H * (x - y)
        y = H * (x + y)
        x = tmp
    elif name == "YAW_90":
        tmp = x
        x = -y
        y = tmp
    elif name == "ROLL_180":
        y, z = -y, -z
    elif name == "ROLL_90_YAW_90":
        tmp = z
        z = y
        y = -tmp
        tmp = x
        x = -y
        y = tmp
    elif name == "PITCH_270":
        tmp = z
        z = x
        x = -tmp
    elif name == "PITCH_180_YAW_90":
        z = -z
        tmp = -x
        x = -y
        y = tmp
    else:
        raise AssertionError(name)
    return np.stack([x, y, z], axis=-1)


RIGHT_ANGLED = ("YAW_90", "ROLL_180", "ROLL_90_YAW_90", "PITCH_270", "PITCH_180_YAW_90")


def test_rotations_are_the_firmwares():
    """Every shared rotation is PX4's Dcm of its rot_lookup angles, the ones ArduPilot's
    rotate() is transcribed for agree; names, prefix and number are accepted."""
    for name, (number, rpy) in autopilot.rotation_names("px4").items():
        rot = autopilot.rotation(name, "px4")
        assert rot.number == number
        np.testing.assert_allclose(rot.matrix, _px4_dcm(*rpy), atol=1e-12)
    e = np.eye(3)
    for name in (*RIGHT_ANGLED, "YAW_45"):
        rot = autopilot.rotation(f"ROTATION_{name}", "ardupilot")
        np.testing.assert_allclose(rot.matrix, _ap_rotate(name, e).T, atol=1e-12)
    assert autopilot.rotation("2", "px4").name == "YAW_90"
    assert autopilot.rotation("ROLL_45", "ardupilot").number == 42
    with pytest.raises(ValueError, match=r"ROLL_45.*not a rotation of px4 \(SENS_BOARD_ROT\)"):
        autopilot.rotation("ROLL_45", "px4")
    with pytest.raises(ValueError, match="AHRS_ORIENTATION"):
        autopilot.rotation("ROLL_90_PITCH_68_YAW_293", "ardupilot")


def _unit_output(cal: Calibration, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """(f, w, raw acc, raw gyr): true inputs and the unit's output in its calibrated axes."""
    f, w = rng.normal(0, 9.8, (50, 3)), rng.normal(0, 1.0, (50, 3))
    acc = (1 + cal.vector("acc", "scale")) * f + cal.vector("acc", "bias")
    return f, w, acc, w + cal.vector("gyr", "bias")


@pytest.mark.parametrize("name", RIGHT_ANGLED)
def test_offsets_and_scales_rotated_as_the_firmware_applies_them(tmp_path, name):
    cal, rng = firmware_calibration(), np.random.default_rng(5)
    f, w, acc, gyr = _unit_output(cal, rng)
    px4 = autopilot.rotation(name, "px4")
    rows, _ = exports.px4_calibration_parameters(cal, accel_id=ACC_ID, gyro_id=GYRO_ID, rot=px4)
    path = tmp_path / "cal.params"
    path.write_text(exports.px4_params_text(rows, vehicle_id=3))
    p = exports.read_px4_params(path)
    r = _px4_dcm(*autopilot.rotation_names("px4")[name][1])
    off_a = np.array([p[f"CAL_ACC0_{a}OFF"] for a in "XYZ"])
    scl = np.array([p[f"CAL_ACC0_{a}SCALE"] for a in "XYZ"])
    off_g = np.array([p[f"CAL_GYRO0_{a}OFF"] for a in "XYZ"])
    np.testing.assert_allclose((acc @ r.T - off_a) * scl, f @ r.T, atol=REL * 30)
    np.testing.assert_allclose(gyr @ r.T - off_g, w @ r.T, atol=REL * 3)
    assert all(ln.startswith("3\t1\t") for ln in path.read_text().splitlines() if ln[0] != "#")
    assert path.read_text().startswith("# Onboard parameters for Vehicle 3\n")

    rows, _ = exports.ardupilot_calibration_parameters(
        cal, rot=autopilot.rotation(name, "ardupilot")
    )
    path = tmp_path / "cal.param"
    path.write_text(exports.ardupilot_params_text(rows))
    q = exports.read_ardupilot_params(path)
    off_a = np.array([q[f"INS_ACCOFFS_{a}"] for a in "XYZ"])
    scl = np.array([q[f"INS_ACCSCAL_{a}"] for a in "XYZ"])
    off_g = np.array([q[f"INS_GYROFFS_{a}"] for a in "XYZ"])
    want_f, want_w = _ap_rotate(name, f), _ap_rotate(name, w)
    np.testing.assert_allclose((_ap_rotate(name, acc) - off_a) * scl, want_f, atol=REL * 30)
    np.testing.assert_allclose(_ap_rotate(name, gyr) - off_g, want_w, atol=REL * 3)
    # the check can fail: the offsets as calibrated, not rotated, miss by the bias itself
    plain = dict(exports.ardupilot_calibration_parameters(cal)[0])
    off_plain = np.array([plain[f"INS_ACCOFFS_{a}"] for a in "XYZ"])
    assert np.abs((_ap_rotate(name, acc) - off_plain) * scl - want_f).max() > 0.1


def test_a_rotation_between_axes_is_refused_where_scales_are_written():
    with pytest.raises(ValueError, match=r"--rotation YAW_45: not a multiple of 90 deg"):
        exports.px4_calibration_parameters(
            firmware_calibration(), accel_id=1, gyro_id=1, rot=autopilot.rotation("YAW_45", "px4")
        )


TEMPS = np.array([-25.0, -10.0, 0.0, 17.3, 35.0, 59.9, 80.0])


def _model() -> ThermalModel:
    coef = {
        "acc.bias.x": [0.12, 3e-3, -4e-5, 6e-7],
        "acc.bias.y": [-0.05, -2e-3, 1e-5],
        "gyr.bias.x": [0.01, 2e-4, -3e-6, 4e-8],
        "gyr.bias.z": [-0.02, -1e-4],
    }
    curves = {
        n: ParameterCurve(n, np.array(c), np.eye(len(c)) * 1e-12, 1.0, 8) for n, c in coef.items()
    }
    return ThermalModel(25.0, -10.0, 60.0, curves)


def _gyro_bias(model: ThermalModel, cal: Calibration, axis: str, T: np.ndarray) -> np.ndarray:
    """The unit's gyro bias at T: the model's curve, else the calibration's constant."""
    name = f"gyr.bias.{axis}"
    return model.value(name, T) if name in model.curves else np.full(len(T), cal.value(name))


@pytest.mark.parametrize("name", ["YAW_45", "ROLL_90_YAW_90"])
def test_thermal_curves_rotated_as_the_firmware_applies_them(name):
    """TC_* by PX4's calc_thermal_offsets_3D and INS_TCAL by ArduPilot's correct_sensor remove
    the rotated bias curve from the rotated output (any rotation: no scales here)."""
    model, cal = _model(), firmware_calibration()
    bias = np.stack([_gyro_bias(model, cal, a, TEMPS) for a in "xyz"], 1)
    w = np.random.default_rng(9).normal(0, 1.0, (len(TEMPS), 3))
    rows = exports.px4_parameters(
        model, cal, accel_id=1, gyro_id=1, rot=autopilot.rotation(name, "px4")
    )
    p = {n: v for n, v, _ in rows}
    dT = np.clip(TEMPS, p["TC_G0_TMIN"], p["TC_G0_TMAX"]) - p["TC_G0_TREF"]
    tc = np.stack([sum(p[f"TC_G0_X{k}_{i}"] * dT**k for k in range(4)) for i in range(3)], 1)
    r = _px4_dcm(*autopilot.rotation_names("px4")[name][1])
    np.testing.assert_allclose((w + bias) @ r.T - tc, w @ r.T, atol=REL * 3)

    q = dict(exports.ardupilot_parameters(model, cal, rot=autopilot.rotation(name, "ardupilot")))

    def poly(T: np.ndarray) -> np.ndarray:  # AP_InertialSensor_TCal::polynomial_eval, x 1e-6
        T = (np.clip(T, q["INS_TCAL1_TMIN"], q["INS_TCAL1_TMAX"]) - 35.0)[:, None]
        c = [np.array([q[f"INS_TCAL1_GYR{k}_{a}"] for a in "XYZ"]) for k in (1, 2, 3)]
        return (c[0] + (c[1] + c[2] * T) * T) * T * 1e-6

    t_cal = np.full(len(TEMPS), 21.5)
    got = _ap_rotate(name, w + bias) - poly(TEMPS) + poly(t_cal)
    at_cal = _ap_rotate(name, np.stack([_gyro_bias(model, cal, a, t_cal) for a in "xyz"], 1))
    np.testing.assert_allclose(got - at_cal, _ap_rotate(name, w), atol=REL * 3)


# --- device ids from the logs, end to end ------------------------------------------------


def _log_run(folder: Path, serial: str, kind: str, segments: dict, temp: float = 20.0) -> Path:
    """One file per segment in the autopilot's log format, with its run.toml."""
    folder.mkdir(parents=True)
    entries = []
    for label, rec in segments.items():
        name = f"{label}.{'ulg' if kind == 'ulog' else 'bin'}"
        if kind == "ulog":
            write_ulog(folder / name, rec, device_ids=(ACC_ID, GYRO_ID))
        else:
            write_dataflash(folder / name, rec, instances=2)
        entries.append({"label": label, "file": name})
    doc = six_position_manifest(serial, temperature_c=temp)
    fmt = {"kind": kind} | ({"instance": 1} if kind == "dataflash" else {})
    doc |= {"format": fmt, "segments": entries}
    (folder / "run.toml").write_text(dumps_toml(doc))
    return folder


def _archive(tmp: Path, folders: list[Path]):
    archive = resolve_archive(str(tmp / "archive"))
    archive.upgrade()
    ids = {}
    for source in discover_runs(folders):
        outcome = process_run(source, archive)
        assert outcome["status"] == "ok", outcome["error"]
        ids[outcome["serial"]] = outcome["run_id"]
    return archive, ids


def _calib(*args: str):
    return CliRunner().invoke(app, list(args))


@pytest.mark.slow
def test_export_takes_the_device_ids_the_log_recorded(tmp_path):
    rng = np.random.default_rng(47)
    sim = six_position_integral_run(random_errors(rng), rng, rate_hz=50.0, static_s=10.5)
    archive, ids = _archive(
        tmp_path,
        [
            _log_run(tmp_path / "ulog", "U-LOG", "ulog", sim.segments),
            _log_run(tmp_path / "df", "U-DF", "dataflash", sim.segments),
        ],
    )
    ulog_run, df_run = ids["U-LOG"], ids["U-DF"]
    root = str(archive.root)
    res = _calib("export", ulog_run, "--archive", root, "--format", "px4", "--vehicle-id", "2")
    assert res.exit_code == 0, res.output
    lines = res.stdout.splitlines()
    rows = {ln.split("\t")[2]: ln.split("\t") for ln in lines if not ln.startswith("#")}
    assert rows["CAL_ACC0_ID"][3] == str(ACC_ID) and rows["CAL_GYRO0_ID"][3] == str(GYRO_ID)
    assert {r[0] for r in rows.values()} == {"2"}
    head = " ".join(ln for ln in lines if ln.startswith("#"))
    assert "unit U-LOG, run " + ulog_run in head and "REBOOT" in head
    assert f"device ids {ACC_ID} (accelerometer) and {GYRO_ID} (gyro), from the run's log" in head
    # the option wins over the log; ArduPilot: the DataFlash instance picks the IMU
    res = _calib("export", ulog_run, "--archive", root, "--format", "px4", "--device-id", "5")
    assert "CAL_ACC0_ID\t5\t" in res.stdout and "CAL_GYRO0_ID\t5\t" in res.stdout
    res = _calib("export", df_run, "--archive", root, "--format", "ardupilot")
    assert res.exit_code == 0, res.output
    assert "INS_ACC2OFFS_X," in res.stdout and "sets IMU 2 (the log's instance 1)" in res.stdout
    res = _calib("export", df_run, "--archive", root, "--format", "px4")
    assert res.exit_code == 2 and "give --device-id" in " ".join(res.stderr.split())
    res = _calib("export", df_run, "--archive", root, "--format", "px4", "--rotation", "YAW_91")
    assert res.exit_code == 2 and "SENS_BOARD_ROT" in res.stderr


@pytest.mark.slow
def test_thermal_export_device_ids_from_the_log_or_refused(tmp_path):
    """`calib thermal export --format px4`: a campaign logged as ULog carries its ids; the same
    campaign from CSV files is refused naming --device-id, and takes the option."""
    rng = np.random.default_rng(20261122)  # scripts/make_data_samples.py's campaign unit:
    base = dataclasses.replace(random_errors(rng), gyr_noise=np.full(3, 0.03 * DEG))
    truth = random_thermal_truth(rng, base=base)  # its 0 and 20 deg C points pass
    points = thermal_campaign(truth, rng, (0.0, 20.0, 40.0, 60.0), rate_hz=50.0, static_s=10.5)
    folders = []
    for i, point in enumerate(points):
        segs = {k: v for k, v in point.run.segments.items()}
        folder = _log_run(tmp_path / f"t{i}", "TH-LOG", "ulog", segs, point.temperature)
        text = (folder / "run.toml").read_text()
        (folder / "run.toml").write_text(text.replace("2026-11-20", f"2026-11-{20 + i}"))
        folders.append(folder)
    archive, _ = _archive(tmp_path, folders)
    root = str(archive.root)
    res = _calib("thermal", "fit", "TH-LOG", "--archive", root)
    assert res.exit_code == 0, res.output
    out = tmp_path / "tc.params"
    res = _calib("thermal", "export", "TH-LOG", str(out), "--format", "px4", "--archive", root)
    assert res.exit_code == 0, res.output
    p = exports.read_px4_params(out)
    assert p["TC_A0_ID"] == ACC_ID and p["TC_G0_ID"] == GYRO_ID
    text = out.read_text()
    assert "REBOOT" in text and "thermal model valid" in text

    # a campaign from CSV files records no ids: refused naming the option, which it takes
    samples = Path(__file__).resolve().parent.parent / "data_samples" / "thermal_IMU-T-0007"
    csv_archive, _ = _archive(tmp_path / "csv", [samples])
    root = str(csv_archive.root)
    assert _calib("thermal", "fit", "IMU-T-0007", "--archive", root).exit_code == 0
    args = ["thermal", "export", "IMU-T-0007", str(out), "--format", "px4", "--archive", root]
    res = _calib(*args)
    assert res.exit_code == 2 and "give --device-id" in " ".join(res.stderr.split())
    res = _calib(*args, "--device-id", "77", "--rotation", "ROLL_180")
    assert res.exit_code == 0, res.output
    p = exports.read_px4_params(out)
    assert p["TC_A0_ID"] == p["TC_G0_ID"] == 77 and "ROLL_180 (number 8" in out.read_text()
