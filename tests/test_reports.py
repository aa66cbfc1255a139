"""Verification at archive time and reports built from the archive (protocol, HTML, PDF).

Runs go through the real `process_run` into a real SQLite archive; reports come
from `calib report` (in-process CLI) reading only the archive. The PDF is
rendered to PNG with poppler's pdftoppm (installed by scripts/ensure_system_packages.sh).
"""

from __future__ import annotations

import base64
import copy
import json
import math
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from serve_sample import quiet_truth
from sqlalchemy import select
from typer.testing import CliRunner

from calib_core.recording import Recording
from calib_core.simulate import TrueErrors, six_position_integral_run
from calib_core.units import STANDARD_GRAVITY
from calib_testing.archives import new_archive, processed_outcome
from calib_testing.run_writers import six_position_manifest, write_csv_run
from pipelines.cli import app
from pipelines.ingest.errors import IngestError
from pipelines.ingest.manifest import parse_manifest
from storage import queries, schema
from storage.db import Archive

DATA_SAMPLES = Path(__file__).resolve().parent.parent / "data_samples"
TILT = math.radians(30.0)


def _manifest(serial: str, day: int, settings: dict | None = None, segments=None) -> dict:
    m = six_position_manifest(serial, started=f"2026-11-{day:02d}T09:00:00+00:00")
    m["run"]["settings"] = settings or {}
    cube = {"kind": "cube", "model": "PC-100", "serial": "CUBE-1", "calibration_due": "2026-11-15"}
    return m | {
        "format": {"acc_unit": "g"},  # reference_acc is then in g too
        "equipment": [cube],
        "segments": segments or [],
    }


def _tilt(truth: TrueErrors, rng: np.random.Generator, n: int = 1000) -> tuple[Recording, list]:
    """A held-out 30 deg tilt about y: f = g (sin 30, 0, cos 30); reference in g."""
    f_true = STANDARD_GRAVITY * np.array([math.sin(TILT), 0.0, math.cos(TILT)])
    f = np.broadcast_to(f_true, (n, 3))
    acc = truth.acc_measured(f) + rng.standard_normal((n, 3)) * truth.acc_noise
    gyr = truth.gyr_measured(np.zeros((n, 3)), f) + rng.standard_normal((n, 3)) * truth.gyr_noise
    rec = Recording(np.arange(n) / 50.0, acc, gyr, np.full(n, 20.0), label="tilt_30")
    return rec, [math.sin(TILT), 0.0, math.cos(TILT)]


def _write_run(folder: Path, truth: TrueErrors, rng, manifest: dict, tilt_error_g: float = 0.0):
    run = six_position_integral_run(truth, rng)
    segments = dict(run.segments)
    tilt, reference = _tilt(truth, rng)
    segments["tilt_30"] = tilt
    reference = [reference[0], reference[1] + tilt_error_g, reference[2]]
    manifest = {
        **manifest,
        "segments": [{"label": "tilt_30", "verification": True, "reference_acc": reference}],
    }
    write_csv_run(segments, folder, manifest)
    return folder


@pytest.fixture
def arch(tmp_path: Path) -> Archive:
    return new_archive(tmp_path)


def _report(arch: Archive, run_id: str, out: Path, *, pdf: bool = True) -> dict:
    args = ["report", run_id, "--archive", str(arch.root), "--output", str(out), "--json"]
    result = CliRunner().invoke(app, args + ([] if pdf else ["--no-pdf"]))
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


class _Resources(HTMLParser):
    """Collects every URL-bearing attribute and the tag nesting of an HTML document."""

    VOID = {"meta", "img", "br", "hr", "link", "input"}

    def __init__(self) -> None:
        super().__init__()
        self.urls: list[str] = []
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.urls += [v or "" for k, v in attrs if k in ("src", "href", "data", "srcset")]
        if tag == "link" or tag == "script":
            self.errors.append(f"<{tag}> element")
        if tag not in self.VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag):
        if not self.stack or self.stack.pop() != tag:
            self.errors.append(f"unbalanced </{tag}>")

    def handle_data(self, data):
        self.text.append(data)


def _check_html(path: Path) -> str:
    doc = path.read_text(encoding="utf-8")
    assert doc.startswith("<!DOCTYPE html>") and "url(" not in doc and "@import" not in doc
    parser = _Resources()
    parser.feed(doc)
    parser.close()
    assert parser.errors == [] and parser.stack == []
    # the figures are SVG charts embedded as data URLs, each a whole SVG document that
    # loads nothing from outside (no reference but to its own fragments)
    svg = "data:image/svg+xml;base64,"
    assert parser.urls and all(u.startswith(svg) for u in parser.urls), parser.urls
    for url in parser.urls:
        chart = base64.b64decode(url[len(svg) :]).decode("utf-8")
        assert chart.startswith("<svg") and chart.rstrip().endswith("</svg>")
        assert not re.search(r"""(?:href|src)\s*=\s*["'](?!#)""", chart), chart[:300]
    return " ".join(parser.text)


def _check_pdf(path: Path, tmp: Path, expected: list[str]) -> list[Path]:
    """Render every page to PNG (into the new folder `tmp`): none blank; the text holds
    every expected string."""
    import matplotlib.image as mpimg  # loaded by the tests that read pages, not at collection
    import pypdf

    tmp.mkdir()
    pdftoppm = shutil.which("pdftoppm")
    assert pdftoppm, "pdftoppm missing: `make test` installs it (scripts/ensure_system_packages.sh)"
    subprocess.run([pdftoppm, "-r", "40", "-png", str(path), str(tmp / "page")], check=True)
    pages = sorted(tmp.glob("page-*.png"))
    reader = pypdf.PdfReader(path)
    assert len(pages) == len(reader.pages) >= 3
    for png in pages:
        img = mpimg.imread(png)[..., :3]
        # a blank page is all white; the sparsest real page (the plot or the last
        # text page) inks well over 0.5 % of its pixels at 40 dpi
        assert (img.min(axis=2) < 0.8).mean() > 0.005, f"{png.name} is blank"
    text = "\n".join(p.extract_text() for p in reader.pages)
    missing = [s for s in expected if s not in text]
    assert missing == [], f"not in the PDF text: {missing}"
    return pages


@pytest.mark.slow
def test_clean_run_passes_all_and_report_is_complete(arch, tmp_path):
    rng = np.random.default_rng(21)
    folder = _write_run(tmp_path / "clean", quiet_truth(rng), rng, _manifest("SIM-R-1", 20))
    outcome = processed_outcome(folder, arch)
    assert outcome["verdict"] == "pass", [c for c in outcome["checks"] if not c["passed"]]
    names = {c["name"] for c in outcome["checks"]}
    assert {"verify:tilt_30:acc", "verify:tilt_30:gyr"} <= names
    assert not any(n.startswith("repeat:") for n in names)  # one run: not judged

    summary = queries.run_summary(arch, outcome["run_id"])
    cal = summary.calibration
    check = cal.step_settings("check")
    assert cal.step_statistics("solve")["held_out"] == ["tilt_30"]
    # the fit did not see the tilt: its residuals list only the twelve fit segments
    assert "tilt_30" not in {r["segment"] for r in cal.document["residuals"]}
    thresholds = check["thresholds"]
    assert check["profile_version"] == thresholds["version"] == "3"
    assert thresholds["verification_limits"]["acc"]["value"] == pytest.approx(0.01 * 9.80665)

    written = _report(arch, outcome["run_id"], tmp_path / "out")
    assert written["verdict"] == "pass"
    protocol = Path(written["protocol"]).read_text()
    assert "SIM-R-1" in protocol and "verify:tilt_30:acc" in protocol and "PASS" in protocol
    text = _check_html(Path(written["html"]))
    for expected in (
        "SIM-R-1",
        "CUBE-1",
        "2026-11-15",
        "LAPSED",
        "Signatures",
        "Repeatability",
        "tilt_30",
        "Verdict: PASS",
        "Not judged",
    ):
        assert expected in text, expected
    _check_pdf(
        Path(written["pdf"]),
        tmp_path / "pages",
        ["SIM-R-1", "Results", "acc.bias.x", "Quality control", "Accuracy verification", "PASS"],
    )


@pytest.mark.slow
def test_missing_cross_coupling_fails_and_report_names_it(arch, tmp_path):
    rng = np.random.default_rng(22)
    truth = quiet_truth(rng)
    truth.acc_M[2, 0] = -0.012  # true x leaks into measured z
    manifest = _manifest("SIM-R-2", 20, settings={"accel_model": "per_axis"})
    outcome = processed_outcome(_write_run(tmp_path / "reduced", truth, rng, manifest), arch)
    assert outcome["verdict"] == "fail"
    failed = {c["name"] for c in outcome["checks"] if not c["passed"]}
    assert {"residual:x_up:acc:mean", "residual:x_dn:acc:mean"} <= failed
    written = _report(arch, outcome["run_id"], tmp_path / "out")
    text = _check_html(Path(written["html"]))
    # the reduced model has no misalignment parameters: the name comes from the diagnosis
    assert "acc.misalign.zx" in text and "cross-coupling" in text
    import pypdf

    assert "acc.misalign.zx" in "\n".join(
        p.extract_text() for p in pypdf.PdfReader(written["pdf"]).pages
    )


def test_verification_point_with_002_g_error_fails(arch, tmp_path):
    rng = np.random.default_rng(23)
    manifest = _manifest("SIM-R-3", 20)
    folder = _write_run(tmp_path / "v", quiet_truth(rng), rng, manifest, tilt_error_g=0.02)
    outcome = processed_outcome(folder, arch)
    assert outcome["verdict"] == "fail"
    by_name = {c["name"]: c for c in outcome["checks"]}
    acc = by_name["verify:tilt_30:acc"]
    assert not acc["passed"] and acc["limit"] == pytest.approx(0.01 * STANDARD_GRAVITY)
    # the error is the planted 0.02 g give or take the fit's own error (<< 1 mg here)
    assert acc["value"] == pytest.approx(0.02 * STANDARD_GRAVITY, abs=0.001 * STANDARD_GRAVITY)
    assert by_name["verify:tilt_30:gyr"]["passed"]
    assert [n for n, c in by_name.items() if c["status"] == "fail"] == ["verify:tilt_30:acc"]


@pytest.mark.slow
def test_three_runs_with_2_percent_scale_change_fail_repeatability(arch, tmp_path):
    rng = np.random.default_rng(24)
    truth = quiet_truth(rng)
    changed = copy.deepcopy(truth)
    changed.acc_M[0, 0] = (1.0 + truth.acc_M[0, 0]) * 1.02 - 1.0  # K_x 2 % larger
    outcomes = []
    for day, t in ((10, truth), (11, changed), (12, truth)):
        folder = _write_run(tmp_path / f"r{day}", t, rng, _manifest("SIM-R-4", day))
        outcomes.append(processed_outcome(folder, arch))
    assert [o["verdict"] for o in outcomes[:2]] == ["pass", "pass"]  # fewer than 3 runs
    third = outcomes[2]
    failed = [c["name"] for c in third["checks"] if c["status"] == "fail"]
    assert failed == ["repeat:acc.scale.x"]
    assert third["verdict"] == "needs review"
    # the archive holds the verdict with the profile version; every check row too
    with arch.engine().connect() as conn:
        rows = conn.execute(
            select(schema.CalibrationRow.verdict, schema.CalibrationRow.profile_version)
        ).all()
        check_versions = set(conn.execute(select(schema.CheckResultRow.profile_version)).scalars())
    assert sorted(rows) == [("needs review", "3"), ("pass", "3"), ("pass", "3")]
    assert check_versions == {"3"}
    summary = queries.run_summary(arch, third["run_id"])
    group = summary.calibration.step_statistics("check")
    assert group["repeatability_group"] == [o["run_id"] for o in outcomes[::-1]]
    written = _report(arch, third["run_id"], tmp_path / "out", pdf=False)
    assert "pdf" not in written
    text = _check_html(Path(written["html"]))
    assert "NEEDS REVIEW" in text and "acc.scale.x" in text and "rule" in text

    # the on-demand command judges the same group from the archive
    result = CliRunner().invoke(
        app, ["repeatability", "SIM-R-4", "--archive", str(arch.root), "--json"]
    )
    assert result.exit_code == 1, result.output
    doc = json.loads(result.stdout)
    assert doc["judged"] and doc["verdict"] == "needs review" and len(doc["group"]) == 3
    assert [c["name"] for c in doc["checks"] if not c["passed"]] == ["repeat:acc.scale.x"]


@pytest.mark.slow
def test_calib_report_on_data_samples_csv_run(arch, tmp_path):
    """`calib report` on the CSV sample run; its PDF pages rendered in the test's folder."""
    outcome = processed_outcome(DATA_SAMPLES / "csv_IMU-2026-0042", arch)
    written = _report(arch, outcome["run_id"], tmp_path / "out")
    assert set(written) >= {"protocol", "html", "pdf"}
    _check_html(Path(written["html"]))
    _check_pdf(
        Path(written["pdf"]),
        tmp_path / "pages",
        ["IMU-2026-0042", "CUBE-7", "2027-06-30", "Equipment", "Environment", "Signatures"],
    )
    # without --output the files go into the run's archive folder
    result = CliRunner().invoke(app, ["report", outcome["run_id"], "--archive", str(arch.root)])
    assert result.exit_code == 0, result.output
    run_dir = arch.root / queries.run_summary(arch, outcome["run_id"]).run_dir
    assert {p.suffix for p in run_dir.iterdir()} >= {".txt", ".html", ".pdf"}


def test_report_of_unknown_run_is_a_clear_error(arch):
    result = CliRunner().invoke(app, ["report", "Rdeadbeef0000", "--archive", str(arch.root)])
    assert result.exit_code == 2 and "Rdeadbeef0000" in result.output


def test_manifest_reference_acc_is_validated(tmp_path):
    manifest = _manifest("SIM-R-5", 20)
    rng = np.random.default_rng(25)
    folder = _write_run(tmp_path / "m", quiet_truth(rng), rng, manifest)
    text = (folder / "run.toml").read_text()
    assert "reference_acc = [0.49999999999999994, 0.0, 0.8660254037844387]" in text
    bad = text.replace("reference_acc = [0.49999999999999994, 0.0, ", "reference_acc = [")
    with pytest.raises(IngestError) as err:
        parse_manifest(bad, "run.toml")
    assert "reference_acc" in str(err.value) and "3 finite numbers" in str(err.value)
    nan = text.replace("reference_acc = [0.49999999999999994,", "reference_acc = [nan,")
    with pytest.raises(IngestError, match=r"reference_acc.*not a finite number"):
        parse_manifest(nan, "run.toml")
