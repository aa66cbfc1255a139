"""CSV variants: each processes to the same parameters as the plain file.

A simulated six_position_integral run is written as plain CSV (one file per
segment, ',' and '.', header ``t,acc_x,..,temp``, SI units, 17 significant
digits) and as each variant: metadata lines before the header (found, or
skipped by ``skip_lines``), ';' with decimal commas, tab with decimal commas,
UTF-8 BOM, quoted fields, CRLF, units in the header names (``acc_x [g]``,
``gyro_x (deg/s)``, ``t [ms]``, ``mg``, ``rad/s``, ``m/s^2``, ``degC``), a
manifest unit overriding the header's, and one file with a ``part`` column
cut into segments. Each is processed into a real SQLite archive and its
parameters compared with the plain run's: the same decimal text gives the same
floats (1e-12 relative covers a different summation order); a unit converted
there and back differs by a few ulp, which moves no parameter by 1e-9 of itself.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from calib_core.simulate import random_errors, six_position_integral_run
from calib_core.units import DEG, STANDARD_GRAVITY
from calib_testing.run_writers import dumps_toml
from pipelines.ingest import IngestError, discover_runs, load_run
from pipelines.ingest.csv_dialect import sniff
from pipelines.ingest.data_format import FormatSpec
from pipelines.process import process_run
from storage.db import resolve_archive

NAMES = ["t", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z", "temp"]
METADATA = ["Device: IMU-42 fw 1.2.3", "Exported 2026-11-20 09:00, operator: A. N.", ""]


@pytest.fixture(scope="module")
def sim():
    rng = np.random.default_rng(1701)
    return six_position_integral_run(random_errors(rng), rng, static_s=8.0)


def columns(rec) -> np.ndarray:
    return np.column_stack([rec.t, rec.acc, rec.gyr, rec.temp])


def fmt_number(x: float, decimal: str) -> str:
    text = f"{x:.17g}"
    return text.replace(".", ",") if decimal == "," else text


def write_table(
    path: Path,
    header: list[str],
    rows: np.ndarray,
    *,
    sep: str = ",",
    decimal: str = ".",
    metadata: list[str] = (),
    quote: bool = False,
    newline: str = "\n",
    bom: bool = False,
    extra: list[str] | None = None,
) -> None:
    """One delimited file: metadata lines, header, rows (extra: a leading text column)."""
    q = (lambda s: f'"{s}"') if quote else (lambda s: s)
    lines = list(metadata) + [sep.join(q(h) for h in header)]
    for i, row in enumerate(rows):
        cells = [q(fmt_number(v, decimal)) for v in row]
        lines.append(sep.join(([q(extra[i])] if extra else []) + cells))
    text = newline.join(lines) + newline
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode())


def manifest(fmt: dict, segments: list[dict]) -> str:
    return dumps_toml(
        {
            "schema_version": 1,
            "unit": {"serial": "CSV-VAR", "model": "SIM", "manufacturer": "calib_core.simulate"},
            "run": {
                "started": "2026-11-20T09:00:00Z",
                "operator": "test",
                "procedure": "six_position_integral",
                "tolerance_profile": "mpu6000",
            },
            "format": fmt,
            "segments": segments,
        }
    )


def per_segment(**kw) -> Callable:
    """A variant writing one file per segment; kw: header (names), scale (per column), fmt."""

    def write(folder: Path, segments) -> None:
        header = kw.get("header", NAMES)
        scale = np.asarray(kw.get("scale", np.ones(8)))
        for label, rec in segments.items():
            write_table(
                folder / f"{label}.csv",
                header,
                columns(rec) / scale,
                **{k: v for k, v in kw.items() if k not in ("header", "scale", "fmt")},
            )
        fmt = {"kind": "csv", **kw.get("fmt", {})}
        segs = [{"label": label, "file": f"{label}.csv"} for label in segments]
        (folder / "run.toml").write_text(manifest(fmt, segs))

    return write


def sectioned(column: str, rename: dict[str, str] | None = None, **kw) -> Callable:
    """One file for the whole run, its rows grouped by a section column."""

    def write(folder: Path, segments) -> None:
        rows, parts, t0 = [], [], 0.0
        for label, rec in segments.items():
            block = columns(rec)
            block[:, 0] = block[:, 0] - block[0, 0] + t0  # one increasing time axis
            t0 = block[-1, 0] + 1.0
            rows.append(block)
            parts += [(rename or {}).get(label, label)] * len(rec)
        write_table(folder / "session.csv", [column, *NAMES], np.vstack(rows), extra=parts, **kw)
        segs = [
            {"label": label, "file": "session.csv"}
            | ({"section": rename[label]} if rename else {"section": label})
            for label in segments
        ]
        (folder / "run.toml").write_text(manifest({"kind": "csv"}, segs))

    return write


G, D = STANDARD_GRAVITY, DEG
UNIT_HEADER = [
    "t [ms]",
    "acc_x [g]",
    "acc_y [g]",
    "acc_z [g]",
    "gyro_x (deg/s)",
    "gyro_y (deg/s)",
    "gyro_z (deg/s)",
    "temperature [degC]",
]
VARIANTS: dict[str, Callable] = {
    "plain": per_segment(),
    "metadata_found": per_segment(metadata=METADATA),
    "metadata_skip_lines": per_segment(
        metadata=["1 2 3 4", "5 6 7 8", "9 10 11 12"], fmt={"skip_lines": 3}
    ),
    "semicolon_comma_decimal": per_segment(sep=";", decimal=","),
    "tab_comma_decimal": per_segment(sep="\t", decimal=","),
    "bom": per_segment(bom=True),
    "quoted_fields": per_segment(quote=True),
    "crlf": per_segment(newline="\r\n"),
    "units_in_header": per_segment(header=UNIT_HEADER, scale=[1e-3, G, G, G, D, D, D, 1]),
    "units_mg_rad_s": per_segment(
        header=["time (s)", "ax (mg)", "ay (mg)", "az (mg)", "wx [rad/s]", "wy [rad/s]",
                "wz [rad/s]", "temp"],
        scale=[1, G * 1e-3, G * 1e-3, G * 1e-3, 1, 1, 1, 1],
    ),
    "units_m_s2_semicolon": per_segment(
        header=["t", "acc_x [m/s^2]", "acc_y [m/s^2]", "acc_z [m/s^2]", "gyr_x", "gyr_y",
                "gyr_z", "temp"], sep=";", decimal=",", metadata=METADATA,
    ),
    "manifest_overrides_header_unit": per_segment(
        header=["t", "acc_x [g]", "acc_y [g]", "acc_z [g]", "gyr_x", "gyr_y", "gyr_z", "temp"],
        fmt={"acc_unit": "m/s^2"},
    ),
    "part_column": sectioned("part"),
    "label_column_renamed_sections": sectioned(
        "label", rename={"x_up": "x_p", "x_dn": "x_a", "x_ccw": "x_rot+", "x_cw": "x_rot-"}
        | {k: k.upper() for k in ("y_up", "y_dn", "y_ccw", "y_cw", "z_up", "z_dn", "z_ccw",
                                    "z_cw")},
        sep=";", decimal=",",
    ),
}  # fmt: skip


def process(folder: Path, archive_dir: Path) -> dict:
    archive = resolve_archive(str(archive_dir))
    archive.upgrade()
    try:
        outcome = process_run(discover_runs([folder])[0], archive)
    finally:
        archive.dispose()
    assert outcome["status"] == "ok", outcome["error"]
    return outcome["parameters"]


@pytest.fixture(scope="module")
def plain(sim, tmp_path_factory: pytest.TempPathFactory) -> dict:
    folder = tmp_path_factory.mktemp("plain") / "run"
    folder.mkdir()
    VARIANTS["plain"](folder, sim.segments)
    return process(folder, folder.parent / "archive")


@pytest.mark.slow  # a whole run processed per variant
@pytest.mark.parametrize("name", sorted(set(VARIANTS) - {"plain"}))
def test_variant_processes_to_plain_parameters(tmp_path: Path, name: str, sim, plain) -> None:
    folder = tmp_path / "run"
    folder.mkdir()
    VARIANTS[name](folder, sim.segments)
    loaded = load_run(discover_runs([folder])[0])
    exact = "unit" not in name
    for label, rec in sim.segments.items():
        got = loaded.segments[label]
        assert len(got) == len(rec), label
        if exact:
            np.testing.assert_array_equal(got.acc, rec.acc)
            np.testing.assert_array_equal(got.gyr, rec.gyr)
            np.testing.assert_array_equal(got.temp, rec.temp)
        else:
            np.testing.assert_allclose(got.acc, rec.acc, rtol=1e-14, atol=1e-14)
            np.testing.assert_allclose(got.gyr, rec.gyr, rtol=1e-14, atol=1e-15)
    params = process(folder, tmp_path / "archive")
    assert params.keys() == plain.keys()
    rel = 1e-12 if exact else 1e-9
    for key, p in plain.items():
        assert params[key]["value"] == pytest.approx(p["value"], rel=rel, abs=1e-15), key


def test_dialect_reported(tmp_path: Path) -> None:
    path = tmp_path / "a.csv"
    write_table(path, UNIT_HEADER, np.ones((3, 8)) + 0.5, sep=";", decimal=",", metadata=METADATA)
    d = sniff(path, FormatSpec(kind="csv"))
    # Two metadata lines and a blank one: the header on line 4.
    assert (d.delimiter, d.decimal, d.header_line, d.data_start) == (";", ",", 4, 5)
    assert d.metadata == METADATA[:2] and d.names == UNIT_HEADER


def test_unmappable_header_lists_found_and_expected(tmp_path: Path, sim) -> None:
    folder = tmp_path / "run"
    folder.mkdir()
    per_segment(header=["t", "foo", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z", "temp"])(
        folder, sim.segments
    )
    with pytest.raises(
        IngestError,
        match=r"no acc_x column recognised.*found: t, foo, acc_y.*"
        r"expected one of acc_x",
    ) as err:
        load_run(discover_runs([folder])[0])
    assert err.value.file.endswith("x_up.csv") and err.value.line == 1


@pytest.mark.parametrize(
    ("header", "message", "field"),
    [
        (["t", "acc_x [g]", "acc_y [mg]", "acc_z [g]"], "carry different units", "format.acc_unit"),
        (
            ["t", "acc_x [furlong]", "acc_y [furlong]", "acc_z [furlong]"],
            "not understood",
            "format.acc_unit",
        ),
        (["t [fortnight]", "acc_x", "acc_y", "acc_z"], "not understood", "format.time_unit"),
    ],
)
def test_bad_header_units(tmp_path: Path, sim, header, message, field) -> None:
    folder = tmp_path / "run"
    folder.mkdir()
    per_segment(header=header + ["gyr_x", "gyr_y", "gyr_z", "temp"])(folder, sim.segments)
    with pytest.raises(IngestError, match=message) as err:
        load_run(discover_runs([folder])[0])
    assert err.value.field == field and err.value.file.endswith(".csv")


def test_section_in_two_blocks(tmp_path: Path) -> None:
    path = tmp_path / "s.csv"
    rows = np.column_stack([np.arange(6.0), np.ones((6, 7))])
    write_table(path, ["part", *NAMES], rows, extra=["a", "a", "b", "b", "a", "a"])
    (tmp_path / "run.toml").write_text(
        manifest({"kind": "csv"}, [{"label": "x_up", "file": "s.csv", "section": "a"}])
    )
    blocks = r"section 'a' comes in two separate blocks \(from line 2"
    with pytest.raises(IngestError, match=blocks) as err:
        load_run(discover_runs([tmp_path])[0])
    assert err.value.line == 6 and err.value.field == "part"


def test_missing_section_lists_the_sections(tmp_path: Path) -> None:
    path = tmp_path / "s.csv"
    rows = np.column_stack([np.arange(4.0), np.ones((4, 7))])
    write_table(path, ["part", *NAMES], rows, extra=["a", "a", "b", "b"])
    (tmp_path / "run.toml").write_text(
        manifest({"kind": "csv"}, [{"label": "x_up", "file": "s.csv", "section": "c"}])
    )
    with pytest.raises(IngestError, match=r"section 'c' is not in s\.csv; its sections are a, b"):
        load_run(discover_runs([tmp_path])[0])
