"""CSV sections whose sample counter restarts: each section is its own time base.

imucal's annotated session (../shared/realdata/imucal_ferraris/annotated_session.csv,
raw counts at 204.8 Hz) holds a whole Ferraris run in one file: a ``part`` column
names each row's section and a ``samples`` counter restarts in every section. It
reads with its own counter as the time column and one ``section`` per segment,
without editing the file; a counter that goes back inside one section is still
refused naming the line.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_ingest_formats_e2e import manifest

from pipelines.ingest import IngestError, discover_runs, load_run
from pipelines.ingest.csv_reader import read_csv, read_csv_sections
from pipelines.ingest.data_format import FormatSpec

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
ANNOTATED = REALDATA / "imucal_ferraris" / "annotated_session.csv"
RATE_HZ = 204.8
SECTIONS = {
    "x_p": "x_up", "x_a": "x_dn", "y_p": "y_up", "y_a": "y_dn", "z_p": "z_up", "z_a": "z_dn",
    "x_rot": "x_cw", "y_rot": "y_cw", "z_rot": "z_cw",
}  # fmt: skip
FORMAT = {
    "kind": "csv", "time_column": "samples", "time_unit": "samples", "sample_rate_hz": RATE_HZ,
    "acc_columns": ["acc_x", "acc_y", "acc_z"], "gyr_columns": ["gyr_x", "gyr_y", "gyr_z"],
    # Raw gyro counts, about 16.4 per deg/s (imucal's reference K_g): read as rad/s they
    # would be beyond what any IMU measures, which every reader refuses.
    "gyr_unit": "counts", "gyr_scale": [16.4, 16.4, 16.4], "gyr_scale_unit": "deg/s",
}  # fmt: skip


def _run(tmp_path: Path, data: Path) -> Path:
    folder = tmp_path / "annotated"
    folder.mkdir()
    shutil.copyfile(data, folder / "session.csv")
    segments = [
        {"label": label, "file": "session.csv", "section": part} for part, label in SECTIONS.items()
    ]
    (folder / "run.toml").write_text(manifest("imucal-annotated", FORMAT, segments))
    return folder


def test_annotated_session_reads_with_its_restarting_counter(tmp_path: Path) -> None:
    if not ANNOTATED.is_file():
        pytest.skip(f"real data not found at {ANNOTATED} (the shared realdata folder is absent)")
    raw = pd.read_csv(ANNOTATED)
    loaded = load_run(discover_runs([_run(tmp_path, ANNOTATED)])[0])
    for part, label in SECTIONS.items():
        rows = raw[raw["part"] == part]
        rec = loaded.segments[label]
        assert len(rec) == len(rows) > 700
        assert np.array_equal(rec.t, rows["samples"].to_numpy() / RATE_HZ)
        assert np.array_equal(rec.acc, rows[["acc_x", "acc_y", "acc_z"]].to_numpy())
        assert np.all(np.diff(rec.t) > 0)
    # The counter restarts: the sections' times overlap, which only sections allow.
    with pytest.raises(IngestError, match=r"line \d+: field 'samples': time not strictly"):
        read_csv(ANNOTATED, FormatSpec(**FORMAT))


def test_counter_going_back_inside_a_section_names_the_line(tmp_path: Path) -> None:
    lines = ["part,samples,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z"]
    lines += [f"a,{k},0,0,9.8,0,0,0" for k in range(5)]
    lines += [f"b,{k},0,0,9.8,0,0,0" for k in (0, 1, 2, 1, 4)]  # line 10 goes back
    data = tmp_path / "s.csv"
    data.write_text("\n".join(lines) + "\n")
    folder = _run(tmp_path, data)
    toml = folder / "run.toml"
    toml.write_text(toml.read_text().replace('"x_p"', '"a"').replace('"x_a"', '"b"'))
    with pytest.raises(IngestError, match=r"line 10: field 'samples': time not strictly") as err:
        load_run(discover_runs([folder])[0])
    assert err.value.file == str(folder / "session.csv")


@pytest.mark.parametrize("restart", [True, False])
def test_time_is_checked_across_blocks_and_restarts_with_a_section(
    tmp_path: Path, monkeypatch, restart: bool
) -> None:
    """Read in 4 kB slices of 64 lines of 64 bytes: section b's counter restarts at the
    first row of a slice (row 64) and is read; the same counter inside one section is
    refused at that row, the line after the previous slice's last."""
    from pipelines.ingest import csv_reader

    monkeypatch.setattr(csv_reader, "SLICE_BYTES", 4096)
    rows = [("a", k) for k in range(64)] + [("b" if restart else "a", k) for k in range(64)]
    lines = [f"{p},{k:07d},0.100000,0.200000,9.800000,0.010000,0.020000,0.030000" for p, k in rows]
    assert {len(line) for line in lines} == {63}
    path = tmp_path / "s.csv"
    path.write_text("\n".join(["part,samples,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z", *lines]) + "\n")
    fmt = FormatSpec(**FORMAT)  # the section column: "part", recognised
    if not restart:
        with pytest.raises(IngestError, match=r"line 66: field 'samples': time not strictly"):
            read_csv_sections(path, fmt)
        return
    parts = read_csv_sections(path, fmt)
    assert list(parts) == ["a", "b"]
    assert np.array_equal(parts["b"].t, np.arange(64) / RATE_HZ)
