"""Run manifest: a complete example loads; every kind of mistake names its field."""

from __future__ import annotations

import math
import tomllib
from datetime import UTC, date, datetime
from pathlib import Path

import pytest

from calib_testing.run_writers import dumps_toml
from pipelines.ingest import IngestError, load_manifest

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
    assert m.format.extra == {"topics": ["/imu"]}


# One case per kind of mistake: the edit of EXAMPLE, the field named, part of the message.
MISTAKES = tomllib.loads((Path(__file__).parent / "manifest_mistakes.toml").read_text("utf-8"))


@pytest.mark.parametrize(
    ("old", "new", "field", "expected"),
    [(c["old"], c["new"], c["field"], c["expected"]) for c in MISTAKES["case"]],
    ids=[f"{c['field']}:{c['new'].strip()}" for c in MISTAKES["case"]],
)
def test_mistakes_name_their_field(
    tmp_path: Path, old: str, new: str, field: str, expected: str
) -> None:
    assert old in EXAMPLE
    err = error_of(tmp_path, EXAMPLE.replace(old, new, 1))
    assert err.field == field and err.file == str(tmp_path / "run.toml")
    text = EXAMPLE.replace(old, new, 1)
    # The line is the one that writes the key (as for a [run.settings] key); none when the
    # key is missing or the problem is a whole section's.
    where = "" if err.line is None else f" line {err.line}"
    assert str(err).startswith(f"{tmp_path / 'run.toml'}{where}: field '{field}': ")
    if err.line is not None:
        assert text.splitlines()[err.line - 1].strip().startswith(field.rsplit(".", 1)[-1])
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


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ("gyro_range_dps = 250", "gyro_range_dps = 1e400", "run.settings.gyro_range_dps"),
        ("end_s = 60.0", "end_s = nan", "segments[1].end_s"),
        ("humidity_pct = 48", "humidity_pct = -inf", "environment.humidity_pct"),
    ],
)
def test_a_number_no_field_holds_is_refused_naming_line_and_key(tmp_path, old, new, field):
    """1e400 reads as infinity: refused before any solve, naming run.toml, line and key."""
    text = EXAMPLE.replace(old, new)
    err = error_of(tmp_path, text)
    line = text.splitlines().index(new) + 1
    assert (err.field, err.line) == (field, line), str(err)
    assert "not a finite number" in str(err) and str(tmp_path / "run.toml") in str(err)


def test_overlapping_windows_of_one_file_are_refused(tmp_path):
    """x_dn starting inside x_up's window (end_s 30 -> 250): one sample in two segments."""
    text = EXAMPLE.replace("end_s = 30.0", "end_s = 250.0")
    err = error_of(tmp_path, text)
    assert err.field == "segments[1]" and "overlaps segment 'x_up'" in str(err)
    assert err.line == text.splitlines().index("start_s = 30.0") + 1
    # Adjacent windows ([0, 30) and [30, 60)) and other files do not overlap.
    load_manifest(write(tmp_path, EXAMPLE))
