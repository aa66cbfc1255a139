"""Headered CSV described by a run manifest: round trip, delimiters, bad input."""

from __future__ import annotations

import hashlib
import re
from dataclasses import replace
from datetime import UTC, date, datetime
from pathlib import Path

import numpy as np
import pytest

from calib_core.recording import Recording
from calib_core.units import (
    DEG,
    STANDARD_GRAVITY,
    acceleration_factor,
    angular_rate_factor,
    time_factor,
)
from calib_testing.run_writers import (
    CSV_ACC_DECIMALS,
    CSV_GYR_DECIMALS,
    CSV_REFERENCE_DECIMALS,
    CSV_TEMP_DECIMALS,
    CSV_TIME_DECIMALS,
    dumps_toml,
    write_csv_run,
)
from pipelines.ingest import FormatSpec, IngestError, discover_runs, load_run, read_csv
from pipelines.ingest.data_format import format_spec
from pipelines.ingest.manifest import SIX_POSITION_LABELS

N = 120  # samples per segment at 100 Hz


def make_segments(rng: np.random.Generator, labels=SIX_POSITION_LABELS) -> dict[str, Recording]:
    """Segments with +-g on one axis, 45 deg/s turns, noise, temperature and a table angle."""
    out = {}
    for label in labels:
        t = np.arange(N) / 100.0 + rng.uniform(0.0, 50.0)  # each on its own clock
        axis = "xyz".index(label[0])
        acc = rng.normal(0.0, 0.02, (N, 3))
        gyr = rng.normal(0.0, 0.005, (N, 3))
        rate = 0.0
        if label.endswith(("up", "dn")):
            acc[:, axis] += STANDARD_GRAVITY if label.endswith("up") else -STANDARD_GRAVITY
        else:
            acc[:, axis] += STANDARD_GRAVITY
            rate = (45.0 if label.endswith("ccw") else -45.0) * DEG
            gyr[:, axis] += rate
        temp = 21.0 + rng.normal(0.0, 0.1, N)
        angle = rate * (t - t[0])
        out[label] = Recording(t, acc, gyr, temp, {"table_angle": angle}, label)
    return out


def manifest_dict(**fmt) -> dict:
    return {
        "unit": {"serial": "IMU-7", "model": "ADIS16470", "manufacturer": "Analog Devices"},
        "run": {
            "started": datetime(2024, 5, 2, 9, 15),
            "operator": "A. Tester",
            "procedure": "six_position_integral",
            "tolerance_profile": "mpu6000",
            "settings": {"turns": 1},
        },
        "site": {"latitude_deg": 48.1, "height_m": 520.0, "gravity_model": "helmert"},
        "environment": {"temperature_c": 21.0, "humidity_pct": 45.0},
        "equipment": [
            {
                "kind": "rate_table",
                "model": "AC1120",
                "serial": "RT-3",
                "accuracy_class": "0.01 %",
                "calibration_due": date(2025, 1, 31),
            }
        ],
        "format": fmt,
    }


def half_ulp(decimals: int, factor: float) -> float:
    """Half a unit of the last printed decimal, converted to SI by `factor`.

    1e-9 relative slack covers the binary representation of the decimal value.
    """
    return 0.5 * 10.0**-decimals * factor * (1 + 1e-9)


@pytest.mark.parametrize(
    ("seed", "units"),
    [
        (0, {}),
        (1, {"acc_unit": "g", "gyr_unit": "deg/s", "time_unit": "ms", "delimiter": ";"}),
        (2, {"acc_unit": "mg", "gyr_unit": "deg/h", "time_unit": "us", "delimiter": "tab"}),
    ],
)
def test_round_trip_through_manifest(tmp_path: Path, seed: int, units: dict) -> None:
    segments = make_segments(np.random.default_rng(seed))
    manifest = manifest_dict(**units)
    manifest["segments"] = [{"label": "z_cw", "verification": True}]
    write_csv_run(segments, tmp_path, manifest)
    (source,) = discover_runs([tmp_path])
    run = load_run(source)

    tu = units.get("time_unit", "s")
    tol_acc = half_ulp(CSV_ACC_DECIMALS, acceleration_factor(units.get("acc_unit", "m/s^2")))
    tol_gyr = half_ulp(CSV_GYR_DECIMALS, angular_rate_factor(units.get("gyr_unit", "rad/s")))
    # Times are compared relative to each segment's first sample: two roundings.
    tol_t = 2 * half_ulp(CSV_TIME_DECIMALS[tu], time_factor(tu))
    assert list(run.segments) == list(SIX_POSITION_LABELS)
    for label, truth in segments.items():
        rec = run.segments[label]
        assert rec.label == label and len(rec) == N
        assert np.abs((rec.t - rec.t[0]) - (truth.t - truth.t[0])).max() <= tol_t
        assert np.abs(rec.acc - truth.acc).max() <= tol_acc
        assert np.abs(rec.gyr - truth.gyr).max() <= tol_gyr
        assert np.abs(rec.temp - truth.temp).max() <= half_ulp(CSV_TEMP_DECIMALS, 1.0)
        ref = rec.reference["table_angle"] - truth.reference["table_angle"]
        assert np.abs(ref).max() <= half_ulp(CSV_REFERENCE_DECIMALS, 1.0)
    assert run.verification_labels == {"z_cw"}
    m = run.manifest
    lat = np.radians(48.1)
    helmert = 9.80616 * (1 - 0.0026373 * np.cos(2 * lat) + 0.0000059 * np.cos(2 * lat) ** 2)
    assert m.gravity() == pytest.approx(helmert - 3.086e-6 * 520.0, abs=1e-12)
    assert m.equipment[0].calibration_due == date(2025, 1, 31)
    assert run.manifest_text == (tmp_path / "run.toml").read_text()
    assert [(r.name, r.format) for r in run.raw_files] == [
        ("run.toml", "manifest"),
        ("imu.csv", "csv"),
    ]
    for raw in run.raw_files:
        assert raw.sha256 == hashlib.sha256(raw.path.read_bytes()).hexdigest()


def write_small_csv(path: Path, rows: list[str], header: str = "t,ax,ay,az,gx,gy,gz") -> Path:
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


FMT = FormatSpec(
    kind="csv",
    time_column="t",
    acc_columns=["ax", "ay", "az"],
    gyr_columns=["gx", "gy", "gz"],
)
GOOD = [f"{i * 0.01:.2f},0.1,0.2,9.8,0.01,0.02,0.03" for i in range(10)]


@pytest.mark.parametrize(
    ("value", "shown"),
    [
        ("abc", "'abc'"),
        ("nan", "'nan'"),
        ("inf", "'inf'"),
        ("", "an empty value (missing column or blank line)"),
    ],
)
def test_bad_value_names_line_and_column(tmp_path: Path, value: str, shown: str) -> None:
    rows = list(GOOD)
    rows[4] = rows[4].replace("9.8", value)  # data row 5 = line 6 after the header
    path = write_small_csv(tmp_path / "imu.csv", rows)
    with pytest.raises(IngestError) as err:
        read_csv(path, FMT)
    assert str(err.value) == f"{path} line 6: field 'az': expected a finite number, got {shown}"


def test_huge_finite_values_are_read_without_error_or_warning(tmp_path: Path) -> None:
    """Finite values whose sum overflows: the reader's quick test (a block's sum) sends
    them to the exact test, which finds nothing to refuse, and says nothing."""
    import warnings

    rows = list(GOOD)
    for i in (3, 4):
        rows[i] = rows[i].replace("9.8", "1.7e308")
    path = write_small_csv(tmp_path / "imu.csv", rows)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = read_csv(path, FMT)
    assert rec.acc[3, 2] == rec.acc[4, 2] == 1.7e308


def test_short_row_is_an_empty_value(tmp_path: Path) -> None:
    rows = list(GOOD)
    rows[2] = rows[2].rsplit(",", 1)[0]  # line 4 lacks gz
    path = write_small_csv(tmp_path / "imu.csv", rows)
    with pytest.raises(IngestError, match=r"line 4: field 'gz': .*empty value"):
        read_csv(path, FMT)


def test_time_not_increasing_names_first_bad_line(tmp_path: Path) -> None:
    rows = list(GOOD)
    rows[6], rows[7] = rows[7], rows[6]  # line 9 goes back in time
    path = write_small_csv(tmp_path / "imu.csv", rows)
    with pytest.raises(IngestError, match="time must increase") as err:
        read_csv(path, FMT)
    assert (err.value.line, err.value.field) == (9, "t")


def test_column_not_in_header(tmp_path: Path) -> None:
    path = write_small_csv(tmp_path / "imu.csv", GOOD, header="t,ax,ay,acc_z,gx,gy,gz")
    with pytest.raises(IngestError, match=r"column 'az'.*header has: t, ax, ay, acc_z") as err:
        read_csv(path, FMT)
    assert err.value.field == "format.acc_columns"


@pytest.mark.parametrize(
    ("delimiter", "sep"), [(None, ";"), (None, "\t"), (None, "  "), ("whitespace", " ")]
)
def test_delimiters(tmp_path: Path, delimiter: str | None, sep: str) -> None:
    rows = [r.replace(",", sep) for r in GOOD]
    path = write_small_csv(
        tmp_path / "imu.txt", rows, header=sep.join(["t", "ax", "ay", "az", "gx", "gy", "gz"])
    )
    fmt = replace(FMT, **{"delimiter": delimiter, "gyr_unit": "deg/s", "acc_unit": "g"})
    rec = read_csv(path, fmt)
    assert np.allclose(rec.t, np.arange(10) * 0.01, rtol=0, atol=1e-15)
    assert np.allclose(rec.acc[:, 2], 9.8 * STANDARD_GRAVITY, rtol=1e-15)
    assert np.allclose(rec.gyr[:, 0], 0.01 * DEG, rtol=1e-15)


def test_no_header_integer_columns(tmp_path: Path) -> None:
    path = tmp_path / "imu.csv"
    path.write_text("\n".join(r.replace(",", " ") for r in GOOD) + "\n")
    fmt = FormatSpec(
        kind="csv", header=False, time_column=0, acc_columns=[1, 2, 3], gyr_columns=[4, 5, 6]
    )
    rec = read_csv(path, fmt)
    assert len(rec) == 10 and rec.acc[0, 2] == 9.8
    bad = replace(fmt, **{"temp_column": 8})
    with pytest.raises(IngestError, match=r"0-based indices below 7") as err:
        read_csv(path, bad)
    assert err.value.field == "format.temp_column"


def test_empty_and_header_only(tmp_path: Path) -> None:
    empty = tmp_path / "empty.csv"
    empty.write_text("\n\n")
    with pytest.raises(IngestError, match=r"empty\.csv: file is empty"):
        read_csv(empty, FMT)
    header_only = write_small_csv(tmp_path / "h.csv", [])
    with pytest.raises(IngestError, match=r"h\.csv: no data rows"):
        read_csv(header_only, FMT)


def per_file_manifest(files: dict[str, str], acc_unit: str = "m/s^2") -> str:
    """A run.toml with one CSV file per segment."""
    doc = manifest_dict(acc_unit=acc_unit)
    doc["schema_version"] = 1
    doc["format"].update(
        kind="csv", time_column="t", acc_columns=["ax", "ay", "az"], gyr_columns=["gx", "gy", "gz"]
    )
    doc["segments"] = [{"label": lab, "file": f} for lab, f in files.items()]
    return dumps_toml(doc)


def test_one_file_per_segment_and_missing_file(tmp_path: Path) -> None:
    files = {lab: f"{lab}.csv" for lab in SIX_POSITION_LABELS}
    for name in files.values():
        write_small_csv(tmp_path / name, GOOD)
    (tmp_path / "run.toml").write_text(per_file_manifest(files))
    run = load_run(discover_runs([tmp_path])[0])
    assert len(run.raw_files) == 13 and run.segments["y_dn"].source == str(tmp_path / "y_dn.csv")
    (tmp_path / "x_dn.csv").unlink()
    with pytest.raises(IngestError) as err:
        load_run(discover_runs([tmp_path])[0])
    assert str(err.value).startswith(f"{tmp_path / 'run.toml'}: field 'segments[1].file'")
    assert "'x_dn.csv' not found" in str(err.value)


def test_segment_file_outside_run_folder(tmp_path: Path) -> None:
    write_small_csv(tmp_path / "x.csv", GOOD)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "run.toml").write_text(per_file_manifest({"x_up": "../x.csv"}))
    with pytest.raises(IngestError, match=r"field 'segments\[0\]\.file': .*'\.\./x\.csv'.*inside"):
        load_run(discover_runs([run_dir])[0])


def test_wrong_unit_in_manifest(tmp_path: Path) -> None:
    write_small_csv(tmp_path / "x.csv", GOOD)
    (tmp_path / "run.toml").write_text(per_file_manifest({"x_up": "x.csv"}, acc_unit="furlong/s^2"))
    with pytest.raises(IngestError) as err:
        load_run(discover_runs([tmp_path])[0])
    lines = (tmp_path / "run.toml").read_text().splitlines()
    line = next(i for i, text in enumerate(lines, 1) if text.startswith("acc_unit"))
    assert str(err.value).startswith(
        f"{tmp_path / 'run.toml'} line {line}: field 'format.acc_unit': unknown acceleration "
        "unit 'furlong/s^2'; expected one of: g, m/s"
    )


def test_window_without_samples(tmp_path: Path) -> None:
    """A window beside the record, or one starting 1e9 s before it, is refused before any
    solve, naming the segment and where the record lies."""
    write_csv_run(make_segments(np.random.default_rng(4), ["x_up"]), tmp_path, manifest_dict())
    toml = tmp_path / "run.toml"
    toml.write_text(
        toml.read_text().replace("end_s = ", "end_s = 1000").replace("start_s = ", "start_s = 999")
    )
    with pytest.raises(
        IngestError,
        match=r"field 'segments\[0\]': segment 'x_up': the window .* 0 s inside it .*spans",
    ):
        load_run(discover_runs([tmp_path])[0])
    write_csv_run(make_segments(np.random.default_rng(4), ["x_up"]), tmp_path, manifest_dict())
    toml.write_text(re.sub(r"start_s = .*", "start_s = -1e9", toml.read_text()))
    with pytest.raises(IngestError, match=r"lies 1e\+09 s outside the record"):
        load_run(discover_runs([tmp_path])[0])


# --- layouts without a manifest's column names, units, time bases ---------------------------


@pytest.mark.parametrize(
    "names",
    [
        ["timestamp", "ax", "ay", "az", "gx", "gy", "gz", "temp"],
        ["Time", "ACC_X", "ACC_Y", "ACC_Z", "Gyro_X", "Gyro_Y", "Gyro_Z", "Temperature"],
        [
            "t",
            "linear_acceleration.x",
            "linear_acceleration.y",
            "linear_acceleration.z",
            "angular_velocity.x",
            "angular_velocity.y",
            "angular_velocity.z",
            "temp_c",
        ],
        ["time", "accel_x", "accel_y", "accel_z", "wx", "wy", "wz", "temp"],
    ],
)
def test_common_column_names_are_recognised(tmp_path: Path, names: list[str]) -> None:
    order = [7, 3, 0, 5, 1, 6, 2, 4]  # shuffled: recognition must go by name, not position
    rng = np.random.default_rng(5)
    data = np.column_stack([np.arange(20) * 0.01, rng.normal(0, 1, (20, 7))])
    header = ",".join(names[i] for i in order)
    rows = [",".join(repr(float(v)) for v in row[order]) for row in data]
    path = write_small_csv(tmp_path / "imu.csv", rows, header=header)
    rec = read_csv(path, FormatSpec(kind="csv", gyr_unit="rad/s"))
    assert np.array_equal(rec.t, data[:, 0])  # repr() round-trips float64 exactly
    assert np.array_equal(rec.acc, data[:, 1:4])
    assert np.array_equal(rec.gyr, data[:, 4:7])
    assert np.array_equal(rec.temp, data[:, 7])


def test_ambiguous_and_unrecognised_columns_list_the_candidates(tmp_path: Path) -> None:
    path = write_small_csv(tmp_path / "a.csv", GOOD, header="t,ax,ay,az,gx,gy,gz")
    (tmp_path / "b.csv").write_text(path.read_text().replace("t,ax,", "t,acc_x,ax,", 1))
    with pytest.raises(IngestError, match=r"ambiguous acc_x column: acc_x, ax") as err:
        read_csv(tmp_path / "b.csv", FormatSpec(kind="csv"))
    assert err.value.line == 1 and err.value.field == "format"
    (tmp_path / "c.csv").write_text(path.read_text().replace("gy,", "yaw_rate,", 1))
    with pytest.raises(IngestError, match=r"no gyr_y column recognised .*expected one of gyr_y"):
        read_csv(tmp_path / "c.csv", FormatSpec(kind="csv"))


def test_raw_counts_with_scale_and_offset(tmp_path: Path) -> None:
    """value = (raw - offset) / scale in the scale's unit, per axis (LSB per g, per deg/s)."""
    rng = np.random.default_rng(6)
    raw = rng.integers(-32768, 32767, (50, 6)).astype(float)
    rows = [f"{i * 0.005:.3f}," + ",".join(f"{v:.0f}" for v in r) for i, r in enumerate(raw)]
    path = write_small_csv(tmp_path / "imu.csv", rows)
    scale_a, offset_a = [16384.0, 16390.0, 16370.0], [12.0, -40.0, 7.0]
    scale_g, offset_g = [131.0, 131.5, 130.5], [-3.0, 5.0, 0.0]
    fmt = replace(
        FMT,
        **{
            "acc_unit": "counts",
            "acc_scale": scale_a,
            "acc_offset": offset_a,
            "acc_scale_unit": "g",
            "gyr_unit": "counts",
            "gyr_scale": scale_g,
            "gyr_offset": offset_g,
            "gyr_scale_unit": "deg/s",
        },
    )
    rec = read_csv(path, fmt)
    expected_acc = (raw[:, :3] - offset_a) / scale_a * STANDARD_GRAVITY
    expected_gyr = (raw[:, 3:] - offset_g) / scale_g * DEG
    # Same operations in another order: a few ulp apart.
    assert np.allclose(rec.acc, expected_acc, rtol=4e-16 * 8, atol=0)
    assert np.allclose(rec.gyr, expected_gyr, rtol=4e-16 * 8, atol=0)


@pytest.mark.parametrize(
    ("update", "problem"),
    [
        ({"acc_unit": "counts"}, "acc_unit = 'counts' needs acc_scale"),
        ({"gyr_scale": [1.0, 1.0, 1.0]}, "gyr_scale applies only to gyr_unit = 'counts'"),
        ({"acc_unit": "counts", "acc_scale": [1.0, 0.0, 1.0]}, "acc_scale must not be 0"),
        ({"time_unit": "samples"}, "time_unit = 'samples' needs sample_rate_hz"),
        ({"acc_scale_unit": "furlong"}, "unknown acceleration unit 'furlong'"),
    ],
)
def test_format_mistakes_are_refused(update: dict, problem: str) -> None:
    fields = {
        "kind": "csv",
        "time_column": "t",
        "acc_columns": ["ax", "ay", "az"],
        "gyr_columns": ["gx", "gy", "gz"],
        **update,
    }
    with pytest.raises(ValueError, match=problem):
        format_spec(fields)


def test_iso_8601_time(tmp_path: Path) -> None:
    stamps = [
        "2024-05-02T09:15:00Z",
        "2024-05-02T11:15:00.25+02:00",  # the same clock, another zone
        "2024-05-02T09:15:00.5",  # no offset: UTC, like the manifest's times
        "2024-05-02 09:15:00.750000001Z",
    ]
    rows = [f"{s},0.1,0.2,9.8,0.01,0.02,0.03" for s in stamps]
    path = write_small_csv(tmp_path / "imu.csv", rows)
    rec = read_csv(path, replace(FMT, **{"time_unit": "iso"}))
    t0 = datetime(2024, 5, 2, 9, 15, tzinfo=UTC).timestamp()
    # float64 Unix seconds resolve 2.4e-7 s at this epoch: that is the tolerance.
    assert np.abs(rec.t - (t0 + np.array([0.0, 0.25, 0.5, 0.750000001]))).max() <= 2.4e-7
    rows[2] = rows[2].replace("09:15:00.5", "09:61:00")
    write_small_csv(path, rows)
    with pytest.raises(IngestError, match=r"line 4: field 't': expected an ISO-8601 time"):
        read_csv(path, replace(FMT, **{"time_unit": "iso"}))


def test_time_from_sample_rate_or_sample_index(tmp_path: Path) -> None:
    rows = [f"{i + 100},0.1,0.2,9.8,0.01,0.02,0.03" for i in range(10)]
    path = write_small_csv(tmp_path / "imu.csv", rows, header="n,ax,ay,az,gx,gy,gz")
    no_time = replace(FMT, **{"time_column": None, "sample_rate_hz": 102.4})
    assert np.array_equal(read_csv(path, no_time).t, np.arange(10) / 102.4)
    index = replace(FMT, **{"time_column": "n", "time_unit": "samples", "sample_rate_hz": 102.4})
    assert np.array_equal(read_csv(path, index).t, np.arange(100, 110) / 102.4)


def test_unix_nanoseconds(tmp_path: Path) -> None:
    ns = 1_714_641_300_000_000_000 + 2_500_000 * np.arange(10)  # 400 Hz
    rows = [f"{v},0.1,0.2,9.8,0.01,0.02,0.03" for v in ns]
    path = write_small_csv(tmp_path / "imu.csv", rows)
    rec = read_csv(path, replace(FMT, **{"time_unit": "ns"}))
    # Parsed as float64 (ulp at 1.7e18 ns: 256 ns) then in seconds (ulp 2.4e-7 s).
    assert np.abs(rec.t - ns / 1e9).max() <= 256e-9 + 2.4e-7


def test_whitespace_without_header_leading_spaces(tmp_path: Path) -> None:
    """The imu_tk text layout: right-aligned columns, no header, exponent notation."""
    lines = [f"   {i * 0.01:.7e}   {33000 + i:.7e}   {-2.5:.7e}   {9.81:.7e}" for i in range(30)]
    path = tmp_path / "acc.txt"
    path.write_text("\n".join(lines) + "\n")
    fmt = FormatSpec(
        kind="csv", header=False, time_column=0, acc_columns=[1, 2, 3], gyr_columns=[1, 2, 3]
    )
    rec = read_csv(path, fmt)
    assert np.array_equal(rec.acc[:, 0], 33000.0 + np.arange(30)) and len(rec) == 30
    lines[17] = lines[17].replace("-2.5000000e+00", "x.5")
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(IngestError) as err:
        read_csv(path, fmt)
    assert (err.value.line, err.value.field) == (18, "2") and "'x.5'" in str(err.value)


def test_streamed_blocks_equal_one_read_and_errors_keep_their_line(
    tmp_path: Path, monkeypatch
) -> None:
    """Tiny slices (and the progress bar): same arrays as one slice, same error lines."""
    from pipelines.ingest import csv_reader

    rng = np.random.default_rng(8)
    data = rng.normal(0.0, 1.0, (3000, 6))
    rows = [f"{i * 0.001:.3f}," + ",".join(repr(float(v)) for v in r) for i, r in enumerate(data)]
    path = write_small_csv(tmp_path / "imu.csv", rows)
    whole = read_csv(path, FMT)
    monkeypatch.setattr(csv_reader, "SLICE_BYTES", 4096)  # ~30 slices, cut at line ends
    streamed = read_csv(path, FMT, progress=True)
    assert np.array_equal(streamed.acc, whole.acc) and np.array_equal(streamed.gyr, data[:, 3:])
    assert np.array_equal(streamed.t, whole.t)
    # Data row 2500 (line 2502, in a late block): text in the ax column.
    rows[2500] = f"{2500 * 0.001:.3f},abc," + ",".join(rows[2500].split(",")[2:])
    write_small_csv(path, rows)
    with pytest.raises(IngestError) as err:
        read_csv(path, FMT)
    assert (err.value.line, err.value.field) == (2502, "ax") and "'abc'" in str(err.value)


def test_split_acc_and_gyr_files_through_the_manifest(tmp_path: Path) -> None:
    acc_rows = [f"{i * 0.01:.2f},0.1,0.2,{9.8 + i:.1f}" for i in range(10)]
    gyr_rows = [f"{i * 0.01:.2f},0.01,{i * 0.5:.1f},0.03" for i in range(10)]
    write_small_csv(tmp_path / "acc.csv", acc_rows, header="t,x,y,z")
    write_small_csv(tmp_path / "gyr.csv", gyr_rows, header="t,x,y,z")
    doc = manifest_dict(time_column="t", acc_columns=["x", "y", "z"], gyr_columns=["x", "y", "z"])
    doc["schema_version"] = 1
    doc["format"]["kind"] = "csv"
    doc["segments"] = [{"label": "x_up", "acc_file": "acc.csv", "gyr_file": "gyr.csv"}]
    (tmp_path / "run.toml").write_text(dumps_toml(doc))
    run = load_run(discover_runs([tmp_path])[0])
    rec = run.segments["x_up"]
    assert np.array_equal(rec.acc[:, 2], 9.8 + np.arange(10))
    assert np.array_equal(rec.gyr[:, 1], 0.5 * np.arange(10))
    assert [f.name for f in run.raw_files] == ["run.toml", "acc.csv", "gyr.csv"]
    write_small_csv(tmp_path / "gyr.csv", gyr_rows[:-1], header="t,x,y,z")
    with pytest.raises(IngestError, match=r"gyr\.csv: has 9 samples but .*acc\.csv has 10"):
        load_run(discover_runs([tmp_path])[0])
    doc["segments"] = [{"label": "x_up", "acc_file": "acc.csv"}]
    (tmp_path / "run.toml").write_text(dumps_toml(doc))
    with pytest.raises(IngestError, match=r"segments\[0\].*both 'acc_file' and 'gyr_file'"):
        load_run(discover_runs([tmp_path])[0])
