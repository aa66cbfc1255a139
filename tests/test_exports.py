"""Firmware export files against the layouts documented in docs/exports.md.

The model has known coefficients; each file is read back and evaluated with
the firmware's own formula (as documented), which must reproduce the model's
bias curve to float32 precision (PX4 stores float32; 9 significant digits are
written, so the relative error is ~1e-7 of the largest term).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from calib_core import params
from calib_core.calibration import Calibration
from calib_core.thermal import ParameterCurve, ThermalModel
from pipelines import exports

COEF = {  # SI per deg C^k around T_ref = 25
    "acc.bias.x": [0.12, 3e-3, -4e-5, 6e-7],
    "acc.bias.y": [-0.05, -2e-3, 1e-5],
    "acc.bias.z": [0.2, 1e-3],
    "gyr.bias.x": [0.01, 2e-4, -3e-6, 4e-8],
    "gyr.bias.y": [-0.02, -1e-4],
    "acc.scale.x": [0.01, 1e-4],
}  # gyr.bias.z has no curve: its constant comes from the calibration


def _model() -> ThermalModel:
    curves = {
        n: ParameterCurve(n, np.array(c), np.eye(len(c)) * 1e-12, 1.0, 8) for n, c in COEF.items()
    }
    return ThermalModel(25.0, -10.0, 60.0, curves)


def _cal() -> Calibration:
    cal = Calibration("six_position_integral", 9.80665)
    cal.add("gyr.bias.z", 0.03, 1e-5)
    cal.add("acc.scale.x", 0.011, 1e-5)
    return cal


TEMPS = np.array([-25.0, -10.0, 0.0, 17.3, 35.0, 59.9, 80.0])  # includes both clip sides


def test_px4_file_layout_and_offsets(tmp_path):
    model, cal = _model(), _cal()
    path = exports.write_px4_params(
        tmp_path / "tc.params",
        exports.px4_parameters(model, cal, accel_id=1310988, gyro_id=2359308),
    )
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    assert all(len(ln.split("\t")) == 5 and ln.startswith("1\t1\t") for ln in lines)
    got = exports.read_px4_params(path)
    expected = {"TC_A_ENABLE", "TC_G_ENABLE"}
    for s in "AG":
        expected |= {f"TC_{s}0_{k}" for k in ("ID", "TREF", "TMIN", "TMAX")}
        expected |= {f"TC_{s}0_X{k}_{i}" for k in range(4) for i in range(3)}
    assert set(got) == expected
    assert got["TC_A0_ID"] == 1310988 and got["TC_G0_ID"] == 2359308
    assert (got["TC_A0_TREF"], got["TC_A0_TMIN"], got["TC_A0_TMAX"]) == (25.0, -10.0, 60.0)

    # PX4 TemperatureCompensation::calc_thermal_offsets_3D, then raw - offset.
    for s, sensor in (("A", "acc"), ("G", "gyr")):
        for i, a in enumerate(params.AXES):
            dT = np.clip(TEMPS, got[f"TC_{s}0_TMIN"], got[f"TC_{s}0_TMAX"]) - got[f"TC_{s}0_TREF"]
            offset = sum(got[f"TC_{s}0_X{k}_{i}"] * dT**k for k in range(4))
            name = params.bias(sensor, a)
            want = model.value(name, TEMPS) if name in model.curves else cal.value(name)
            np.testing.assert_allclose(offset, want, rtol=2e-7, atol=1e-9)


def test_px4_legacy_scale(tmp_path):
    rows = dict((n, v) for n, v, _ in exports.px4_parameters(_model(), _cal(), legacy_scale=True))
    assert rows["TC_A0_SCL_0"] == pytest.approx(1.0 / 1.01)  # the curve at T_ref, not the cal
    assert rows["TC_A0_SCL_1"] == 1.0 and "TC_G0_SCL_0" not in rows


def test_ardupilot_file_layout_and_correction(tmp_path):
    model = _model()
    path = exports.write_ardupilot_params(
        tmp_path / "tcal.param", exports.ardupilot_parameters(model, imu=2), header="unit 7"
    )
    text = path.read_text()
    assert text.startswith("# unit 7\n")
    got = exports.read_ardupilot_params(path)
    expected = {"INS_TCAL2_ENABLE", "INS_TCAL2_TMIN", "INS_TCAL2_TMAX"} | {
        f"INS_TCAL2_{s}{k}_{a}" for s in ("ACC", "GYR") for k in (1, 2, 3) for a in "XYZ"
    }
    assert set(got) == expected
    assert got["INS_TCAL2_ENABLE"] == 1

    # AP_InertialSensor_TCal::correct_sensor: v -= poly(T - 35); v += poly(T_cal - 35),
    # poly = (c1 + (c2 + c3 dT) dT) dT * 1e-6, T and T_cal clipped to [TMIN, TMAX].
    def poly(tag: str, axis: str, T: np.ndarray) -> np.ndarray:
        T = np.clip(T, got["INS_TCAL2_TMIN"], got["INS_TCAL2_TMAX"]) - 35.0
        c = [got[f"INS_TCAL2_{tag}{k}_{axis}"] for k in (1, 2, 3)]
        return (c[0] + (c[1] + c[2] * T) * T) * T * 1e-6

    t_cal = 21.5
    for tag, sensor in (("ACC", "acc"), ("GYR", "gyr")):
        for a in params.AXES:
            name = params.bias(sensor, a)
            change = poly(tag, a.upper(), TEMPS) - poly(tag, a.upper(), np.array(t_cal))
            want = (
                model.value(name, TEMPS) - model.value(name, t_cal)
                if name in model.curves
                else np.zeros_like(TEMPS)
            )
            scale = max(np.abs(model.value(name, TEMPS)).max(), 1e-3) if name in model.curves else 1
            np.testing.assert_allclose(change, want, rtol=0, atol=1e-6 * scale)


def test_orders_above_three_are_refused():
    model = _model()
    model.curves["gyr.bias.y"] = ParameterCurve(
        "gyr.bias.y", np.array([0, 1e-4, 0, 0, 1e-9]), np.eye(5), 1.0, 9
    )
    with pytest.raises(ValueError, match="order 4 does not fit this format"):
        exports.px4_parameters(model)
    with pytest.raises(ValueError, match="order 4"):
        exports.ardupilot_parameters(model)


def test_canonical_json_round_trip(tmp_path):
    model = _model()
    doc = exports.canonical_json(model, {"calibration": _cal().to_dict()}, {"serial": "U1"})
    path = exports.write_json(tmp_path / "export.json", doc)
    back = json.loads(path.read_text())
    assert back["format"] == exports.EXPORT_FORMAT and back["format_version"] == 1
    again = ThermalModel.from_dict(back["thermal_model"])
    for T in TEMPS:
        assert again.parameters_at(T) == model.parameters_at(T)
    assert Calibration.from_dict(back["calibration"]["calibration"]).value("gyr.bias.z") == 0.03


def test_bad_lines_name_file_and_line(tmp_path):
    bad = tmp_path / "bad.param"
    bad.write_text("INS_TCAL1_ENABLE,1\nINS_TCAL1_TMIN 1 2\n")
    with pytest.raises(ValueError, match=r"bad\.param:2: expected NAME,VALUE"):
        exports.read_ardupilot_params(bad)
