"""Run manifest: a complete example loads; every kind of mistake names its field."""

from __future__ import annotations

import math
import tomllib
from datetime import UTC, date, datetime
from pathlib import Path

import pytest

from pipelines.ingest import IngestError, load_manifest
from pipelines.run_writers import dumps_toml

EXAMPLE = """\
schema_version = 1

[unit]
serial = "SN-0042"
model = "MPU-6000"
manufacturer = "InvenSense"
specification = "+-2 g, +-250 deg/s"

[run]
started = 2024-05-02T09:15:00
operator = "A. Tester"
procedure = "six_position_integral"
tolerance_profile = "mpu6000"

[run.settings]
turns = 2
gyro_range_dps = 250

[site]
latitude_deg = 55.75
height_m = 150.0
gravity_model = "helmert"

[environment]
temperature_c = 20.5
humidity_pct = 48
pressure_hpa = 1013.2
vibration = "none noticeable"
warmup_min = 15

[[equipment]]
kind = "rate_table"
model = "AC1120"
serial = "RT-3"
accuracy_class = "0.001 deg/s"
calibration_due = 2025-01-31
calibrated_on = 2024-01-31

[format]
kind = "csv"
time_column = "t"
time_unit = "ms"
acc_columns = ["ax", "ay", "az"]
acc_unit = "g"
gyr_columns = ["gx", "gy", "gz"]
gyr_unit = "deg/s"
temp_column = "temp"

[[segments]]
label = "x_up"
file = "imu.csv"
start_s = 0.0
end_s = 30.0

[[segments]]
label = "x_dn"
file = "imu.csv"
start_s = 30.0
end_s = 60.0

[[segments]]
label = "tilt_45"
file = "verify.csv"
verification = true
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "run.toml"
    path.write_text(text)
    return path


def error_of(tmp_path: Path, text: str) -> IngestError:
    with pytest.raises(IngestError) as err:
        load_manifest(write(tmp_path, text))
    return err.value


def test_example_loads(tmp_path: Path) -> None:
    m = load_manifest(write(tmp_path, EXAMPLE))
    assert m.unit.serial == "SN-0042" and m.run.settings == {"turns": 2, "gyro_range_dps": 250}
    assert m.run.started == datetime(2024, 5, 2, 9, 15, tzinfo=UTC)  # naive is taken as UTC
    assert m.equipment[0].calibration_due == date(2025, 1, 31)
    assert m.environment.vibration == "none noticeable"
    assert [s.label for s in m.segments] == ["x_up", "x_dn", "tilt_45"]
    assert m.verification_labels() == {"tilt_45"}
    assert m.segments[2].start_s is None and m.format.delimiter is None
    # Helmert with free-air correction, written out independently of calib_core.earth.
    c2 = math.cos(math.radians(2 * 55.75))
    expected = 9.80616 * (1 - 0.0026373 * c2 + 0.0000059 * c2**2) - 3.086e-6 * 150.0
    assert m.gravity() == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize(
    ("started", "utc"),
    [
        ("2024-05-02T11:15:00+02:00", datetime(2024, 5, 2, 9, 15, tzinfo=UTC)),
        ('"2024-05-02T04:15:00-05:00"', datetime(2024, 5, 2, 9, 15, tzinfo=UTC)),
        ('"2024-05-02 09:15:00"', datetime(2024, 5, 2, 9, 15, tzinfo=UTC)),
    ],
)
def test_started_is_converted_to_utc(tmp_path: Path, started: str, utc: datetime) -> None:
    text = EXAMPLE.replace("started = 2024-05-02T09:15:00", f"started = {started}")
    assert load_manifest(write(tmp_path, text)).run.started == utc


def test_other_gravity_models(tmp_path: Path) -> None:
    standard = EXAMPLE.replace('gravity_model = "helmert"', 'gravity_model = "standard"')
    assert load_manifest(write(tmp_path, standard)).gravity() == 9.80665
    measured = EXAMPLE.replace(
        'gravity_model = "helmert"', 'gravity_model = "measured"\ngravity = 9.81234'
    )
    assert load_manifest(write(tmp_path, measured)).gravity() == 9.81234


def test_format_keeps_extra_keys_for_other_readers(tmp_path: Path) -> None:
    text = EXAMPLE.replace('kind = "csv"', 'kind = "csv"\ntopics = ["/imu"]')
    m = load_manifest(write(tmp_path, text))
    assert m.format.model_extra == {"topics": ["/imu"]}


@pytest.mark.parametrize(
    ("old", "new", "field", "expected"),
    [
        (
            'acc_unit = "g"',
            'acc_unit = "furlong/s^2"',
            "format.acc_unit",
            "unknown acceleration unit 'furlong/s^2'; expected one of: g, m/s2, m/s^2, mg, ug",
        ),
        (
            'gyr_unit = "deg/s"',
            'gyr_unit = "deg/min"',
            "format.gyr_unit",
            "unknown angular rate unit 'deg/min'",
        ),
        ('time_unit = "ms"', 'time_unit = "fortnight"', "format.time_unit", "unknown time unit"),
        ('serial = "SN-0042"', 'serial = "../../etc"', "unit.serial", "invalid serial '../../etc'"),
        (
            'file = "verify.csv"',
            'file = "../x.csv"',
            "segments[2].file",
            "'../x.csv' must be a relative name inside the run folder",
        ),
        ('file = "verify.csv"', 'file = "/etc/passwd"', "segments[2].file", "relative name"),
        (
            'file = "verify.csv"',
            'file = "C:\\\\data\\\\x.csv"',
            "segments[2].file",
            "relative name",
        ),
        (
            'label = "x_dn"',
            'label = "x_dwn"',
            "segments[1].label",
            "'x_dwn' is not a segment label of procedure 'six_position_integral' "
            "(did you mean 'x_dn'?)",
        ),
        ('label = "x_dn"', 'label = "x_up"', "segments[1].label", "repeats segments[0]"),
        (
            'operator = "A. Tester"',
            'opertor = "A. Tester"',
            "run.opertor",
            "unknown field; did you mean 'operator'?",
        ),
        ('model = "MPU-6000"\n', "", "unit.model", "required field is missing"),
        ("schema_version = 1", "schema_version = 2", "schema_version", "Input should be 1"),
        (
            'gravity_model = "helmert"',
            'gravity_model = "egm2008"',
            "site.gravity_model",
            "Input should be 'standard', 'helmert', 'wgs84' or 'measured'",
        ),
        ("latitude_deg = 55.75\n", "", "site", "gravity_model 'helmert' needs latitude_deg"),
        (
            "latitude_deg = 55.75",
            "latitude_deg = 155.75",
            "site.latitude_deg",
            "less than or equal to 90",
        ),
        (
            "calibration_due = 2025-01-31",
            'calibration_due = "next year"',
            "equipment[0].calibration_due",
            "got 'next year'",
        ),
        ('kind = "csv"', 'kind = "xlsx"', "format.kind", "unknown format kind 'xlsx'"),
        ('time_column = "t"\n', "", "format", "format kind 'csv' needs time_column"),
        (
            'acc_columns = ["ax", "ay", "az"]',
            'acc_columns = ["ax", "ay"]',
            "format.acc_columns",
            "expected 3 columns (x, y, z), got 2",
        ),
        (
            "end_s = 60.0",
            "end_s = 20.0",
            "segments[1]",
            "end_s (20.0) must be greater than start_s (30.0)",
        ),
        (
            'tolerance_profile = "mpu6000"',
            'tolerance_profile = "../secret"',
            "run.tolerance_profile",
            "invalid tolerance profile name",
        ),
    ],
)
def test_mistakes_name_their_field(
    tmp_path: Path, old: str, new: str, field: str, expected: str
) -> None:
    assert old in EXAMPLE
    err = error_of(tmp_path, EXAMPLE.replace(old, new, 1))
    assert err.field == field and err.file == str(tmp_path / "run.toml")
    assert str(err).startswith(f"{tmp_path / 'run.toml'}: field '{field}': ")
    assert expected in str(err)


def test_segments_required_for_csv(tmp_path: Path) -> None:
    err = error_of(tmp_path, EXAMPLE[: EXAMPLE.index("[[segments]]")])
    assert err.field == "segments" and "needs a [[segments]] list" in str(err)


def test_toml_syntax_error_names_the_line(tmp_path: Path) -> None:
    err = error_of(tmp_path, EXAMPLE.replace('operator = "A. Tester"', "operator = A. Tester"))
    assert err.line == 11 and f"{tmp_path / 'run.toml'} line 11: not valid TOML" in str(err)


def test_missing_and_binary_manifest(tmp_path: Path) -> None:
    with pytest.raises(IngestError, match="manifest file not found"):
        load_manifest(tmp_path / "run.toml")
    err = error_of(tmp_path, "")
    assert "required field is missing" in str(err)
    (tmp_path / "run.toml").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(IngestError, match="not UTF-8"):
        load_manifest(tmp_path / "run.toml")


def test_toml_writer_round_trip() -> None:
    doc = {
        "schema_version": 1,
        "unit": {"serial": "A1", "model": 'quote " and \\ and ü', "manufacturer": "x"},
        "run": {
            "started": datetime(2024, 1, 2, 3, 4, 5, tzinfo=UTC),
            "settings": {"turns": 2, "solver": {"tol": 1e-12, "flags": [True, False]}},
        },
        "equipment": [{"kind": "daq", "calibration_due": date(2025, 1, 1), "skipped": None}],
        "odd key": [1.5, -0.0, float("inf")],
    }
    back = tomllib.loads(dumps_toml(doc))
    doc["equipment"][0].pop("skipped")  # TOML has no null: None values are left out
    assert back == doc
