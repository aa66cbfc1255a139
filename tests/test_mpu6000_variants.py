"""MPU-6000 text variants: every variant of the sample run processes to
the same parameters as the plain files.

Each variant rewrites the 12 files of data_samples/mpu6000_MPU0001 (summary lines
labelled or not, 6/7/8 numbers, comma decimals, tab or semicolon separators, CRLF
or CR line ends, UTF-8 BOM, cp1251 header and comment lines, trailing blank lines,
file names with '-', upper case, 'down'), keeps the files' modification times
(the synthesised manifest's start time), processes the run into a real SQLite
archive and compares every parameter with the plain run's. The numbers are the
same decimal text, so the values agree to float rounding (1e-12 relative covers
a different summation order; a misread column is off by far more).
"""

from __future__ import annotations

import os
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from pipelines.ingest import IngestError, discover_runs, load_run
from pipelines.ingest.mpu6000 import read_mpu6000_text
from pipelines.process import process_run
from storage.db import resolve_archive

SAMPLE = Path(__file__).resolve().parents[1] / "data_samples" / "mpu6000_MPU0001"
SERIAL = "MPU0001"
CYRILLIC_HEADER = "Калибровка MPU-6000, стенд №2\nВремя,мс ax ay az gx gy gz T\n"


def process(folder: Path, archive_dir: Path) -> dict:
    archive = resolve_archive(str(archive_dir))
    archive.upgrade()
    try:
        (source,) = discover_runs([folder])
        outcome = process_run(source, archive)
    finally:
        archive.dispose()
    assert outcome["status"] == "ok", outcome["error"]
    return outcome["parameters"]


@pytest.fixture(scope="module")
def plain_parameters(tmp_path_factory: pytest.TempPathFactory) -> dict:
    return process(SAMPLE, tmp_path_factory.mktemp("plain") / "archive")


def split_summary(text: str) -> tuple[str, list[str], list[str]]:
    """(data part with the underline, mean tokens, std tokens) of a plain file."""
    lines = text.splitlines()
    return "\n".join(lines[:-2]) + "\n", lines[-2].split(), lines[-1].split()


def summary(fmt: str, keep: slice) -> Callable[[str], str]:
    """Summary lines rewritten: `fmt` with {label} and {numbers}, only the columns `keep`."""

    def edit(text: str) -> str:
        head, means, stds = split_summary(text)
        return head + "".join(
            fmt.format(label=label, numbers="  ".join(tokens[keep])) + "\n"
            for label, tokens in (("mean", means), ("std", stds))
        )

    return edit


def comma_decimals(sep: str) -> Callable[[str], str]:
    def edit(text: str) -> str:
        return (
            "\n".join(
                sep.join(line.replace(".", ",").split()) if line[:1] != "_" else line
                for line in text.splitlines()
            )
            + "\n"
        )

    return edit


# name: (text edit, encoding, file-name edit)
VARIANTS: dict[str, tuple[Callable[[str], str], str, Callable[[str], str]]] = {
    "summary_6_unlabelled": (summary("{numbers}", slice(1, 7)), "ascii", str),
    "summary_7_acc_gyr_temp": (summary("{numbers}", slice(1, 8)), "ascii", str),
    "summary_7_time_acc_gyr": (summary("{numbers}", slice(0, 7)), "ascii", str),
    "summary_8_labelled": (summary("{label} {numbers}", slice(0, 8)), "ascii", str),
    "summary_6_label_equals_upper": (
        lambda t: summary("{label} = {numbers}", slice(1, 7))(t).replace("mean", "MEAN"),
        "ascii",
        str,
    ),
    "summary_7_label_colon": (summary("{label}: {numbers}", slice(1, 8)), "ascii", str),
    "comma_decimals_tab": (comma_decimals("\t"), "ascii", str),
    "comma_decimals_semicolon": (comma_decimals(";"), "ascii", str),
    "comma_decimals_space": (comma_decimals("   "), "ascii", str),
    "semicolon_points": (
        lambda t: "\n".join(
            ";".join(line.split()) + ";" if line[:1] != "_" else line for line in t.splitlines()
        ),
        "ascii",
        str,
    ),
    "crlf": (lambda t: t.replace("\n", "\r\n"), "ascii", str),
    "cr": (lambda t: t.replace("\n", "\r"), "ascii", str),
    "utf8_bom": (lambda t: "\ufeff" + t, "utf-8", str),
    "cp1251_header_crlf_labelled": (
        lambda t: (
            "# Протокол: Gstdx = 0,02089\n"
            + CYRILLIC_HEADER
            + summary("{label}={numbers}", slice(1, 7))(t)
        ).replace("\n", "\r\n"),
        "cp1251",
        str,
    ),
    "utf8_header_and_comments": (
        lambda t: "# лаборатория\n" + CYRILLIC_HEADER + t.replace("\n", "\n# ок\n", 1),
        "utf-8",
        str,
    ),
    "trailing_blank_lines": (lambda t: t + "\n\n  \n\n", "ascii", str),
    "names_dash_upper_down": (
        str,
        "ascii",
        lambda n: n.replace("_", "-").replace("dn", "down").upper().replace(".TXT", ".txt"),
    ),
    "names_mixed_case_ext": (
        str,
        "ascii",
        lambda n: n.replace("_x_", "-X_").replace(".txt", ".TXT"),
    ),
}


def write_variant(folder: Path, name: str) -> None:
    edit, encoding, rename = VARIANTS[name]
    folder.mkdir()
    for src in sorted(SAMPLE.glob(f"{SERIAL}_*.txt")):
        dst = folder / rename(src.name)
        dst.write_bytes(edit(src.read_text()).encode(encoding))
        stat = src.stat()
        os.utime(dst, ns=(stat.st_atime_ns, stat.st_mtime_ns))


@pytest.mark.slow  # a whole run processed per variant
@pytest.mark.parametrize("name", sorted(VARIANTS))
def test_variant_processes_to_plain_parameters(
    tmp_path: Path, name: str, plain_parameters: dict
) -> None:
    write_variant(tmp_path / "run", name)
    (source,) = discover_runs([tmp_path / "run"])
    assert source.serial == SERIAL
    plain = load_run(discover_runs([SAMPLE])[0])
    loaded = load_run(source)
    for label, rec in plain.segments.items():
        got = loaded.segments[label]
        np.testing.assert_array_equal(got.acc, rec.acc)
        np.testing.assert_array_equal(got.gyr, rec.gyr)
        np.testing.assert_array_equal(got.t, rec.t)
        np.testing.assert_array_equal(got.temp, rec.temp)
    params = process(tmp_path / "run", tmp_path / "archive")
    assert params.keys() == plain_parameters.keys()
    for key, p in plain_parameters.items():
        assert params[key]["value"] == pytest.approx(p["value"], rel=1e-12, abs=1e-15), key


def test_variant_is_reported(tmp_path: Path) -> None:
    write_variant(tmp_path / "run", "cp1251_header_crlf_labelled")
    _, variant = read_mpu6000_text(tmp_path / "run" / f"{SERIAL}_x_up.txt")
    assert variant.encoding == "cp1251" and variant.line_end == "CRLF"
    assert variant.header_lines == 2 and variant.comment_lines == 1
    assert "means labelled 'mean', 6 numbers" in variant.describe()
    assert "columns ax ay az gx gy gz" in variant.describe()


@pytest.mark.parametrize("keep", [slice(1, 7), slice(1, 8), slice(0, 7), slice(0, 8)])
def test_printed_mean_off_by_more_than_its_precision(tmp_path: Path, keep: slice) -> None:
    """A summary that disagrees with the data is reported with its line and column."""
    text = summary("{label}: {numbers}", keep)((SAMPLE / f"{SERIAL}_y_up.txt").read_text())
    lines = text.splitlines()
    # az's printed mean (5 decimals) moved by 2e-4: beyond half a unit of its last digit
    # plus half a unit of the data's last digit (0.5e-5 + 0.5e-4).
    tokens = lines[-2].split()
    i = 1 + (3 - keep.start)  # after the label: [time] ax ay az
    tokens[i] = f"{float(tokens[i]) + 2e-4:.5f}"
    lines[-2] = " ".join(tokens)
    path = tmp_path / f"{SERIAL}_y_up.txt"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(IngestError, match=r"printed means disagree.*column 'az'") as err:
        read_mpu6000_text(path)
    assert err.value.line == len(lines) - 1 and err.value.file == str(path)


def test_printed_mean_within_precision_is_accepted(tmp_path: Path) -> None:
    """The same edit by 4e-5 (< 0.5e-5 + 0.5e-4) is rounding, not a disagreement."""
    lines = (SAMPLE / f"{SERIAL}_y_up.txt").read_text().splitlines()
    tokens = lines[-2].split()
    tokens[3] = f"{float(tokens[3]) + 4e-5:.5f}"
    lines[-2] = " ".join(tokens)
    path = tmp_path / f"{SERIAL}_y_up.txt"
    path.write_text("\n".join(lines) + "\n")
    read_mpu6000_text(path)


@pytest.mark.parametrize(
    ("means", "stds", "message"),
    [
        ("mean 1 2 3 4 5", "std 1 2 3 4 5 6", r"expected the column means \(6, 7 or 8 numbers"),
        (None, "avg 1 2 3 4 5 6", r"optional label 'mean' or 'std'"),
        ("std {m}", "std {s}", "second line of standard deviations"),
        ("mean {m}", "std {s6}", r"as many as the 8 means"),
    ],
)
def test_bad_summary_lines(tmp_path: Path, means, stds, message) -> None:
    head, m, s = split_summary((SAMPLE / f"{SERIAL}_z_up.txt").read_text())
    fill = {"m": " ".join(m), "s": " ".join(s), "s6": " ".join(s[1:7])}
    first = (means or "mean {m}").format(**fill)
    path = tmp_path / f"{SERIAL}_z_up.txt"
    path.write_text(head + first + "\n" + stds.format(**fill) + "\n")
    with pytest.raises(IngestError, match=message) as err:
        read_mpu6000_text(path)
    assert err.value.line is not None and err.value.file == str(path)


def test_two_files_for_one_segment(tmp_path: Path) -> None:
    shutil.copytree(SAMPLE, tmp_path / "run")
    shutil.copy(tmp_path / "run" / f"{SERIAL}_x_dn.txt", tmp_path / "run" / f"{SERIAL}_x_down.txt")
    with pytest.raises(IngestError, match=r"two files of serial 'MPU0001' segment 'x_dn'"):
        discover_runs([tmp_path / "run"])


def test_binary_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / f"{SERIAL}_x_up.txt"
    path.write_bytes(b"0 1 2\x00\x01")
    with pytest.raises(IngestError, match="NUL byte at offset 5"):
        read_mpu6000_text(path)


def test_cyrillic_header_is_not_silently_taken_as_data(tmp_path: Path) -> None:
    """A data line that is not numbers after the first data line is an error with its line."""
    text = (SAMPLE / f"{SERIAL}_x_up.txt").read_text().splitlines()
    text.insert(5, "Время 1 2 3")
    path = tmp_path / f"{SERIAL}_x_up.txt"
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(IngestError, match="expected 8 numeric columns") as err:
        read_mpu6000_text(path)
    assert err.value.line == 6
    assert re.search(r"line 6", str(err.value))
