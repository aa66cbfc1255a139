"""Samples the despiker replaced are counted, archived and shown: a run through the archive.

A simulated six-position + integral run whose rotation records carry 0.5 % spikes of
30 noise stds, written as a CSV run folder and processed into a real SQLite archive:
the solve step's archived statistics count the replaced samples per rotation and
channel, each rotation's ``model:replaced:despike:<segment>`` check fails (more than
false alarms explain) and sends the run for review ("needs review": a finding about the
record, the unit's parameters all in tolerance), and `calib show`, the protocol, the
certificate and the web page show every count beside the verdict. The same run without
spikes replaces nothing.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from calib_core.simulate import random_errors, six_position_integral_run
from calib_core.solvers.integral import ROTATION_LABELS
from calib_testing.run_writers import six_position_manifest, write_csv_run
from pipelines.cli import app
from pipelines.ingest import discover_runs
from pipelines.process import process_run
from storage import queries
from storage.db import resolve_archive


def _spiked_run(seed: int, spikes: bool):
    rng = np.random.default_rng(seed)
    truth = random_errors(rng)
    truth.gyr_noise[:] = np.radians(0.04)  # deg/s: a unit within the profile's 0.05
    run = six_position_integral_run(truth, rng)
    if not spikes:
        return run, {}
    segments, injected = dict(run.segments), {}
    for label in ROTATION_LABELS:
        rec = segments[label]
        rows = rng.choice(np.arange(25, len(rec) - 25), 8, replace=False)
        cols = rng.integers(0, 3, rows.size)
        gyr = rec.gyr.copy()
        gyr[rows, cols] += rng.choice([-1.0, 1.0], rows.size) * 30 * run.truth.gyr_noise[cols]
        segments[label] = dataclasses.replace(rec, gyr=gyr)
        injected[label] = rows.size
    return dataclasses.replace(run, segments=segments), injected


def _process(tmp_path: Path, name: str, spikes: bool):
    run, injected = _spiked_run(5, spikes)
    manifest = six_position_manifest(f"SIM-SPIKE-{name}")
    folder = write_csv_run(run.segments, tmp_path / name, manifest).parent
    arch = resolve_archive(str(tmp_path / "archive"))
    arch.upgrade()
    result = process_run(discover_runs([folder])[0], arch)
    assert result["status"] == "ok", result
    return arch, result, injected


def test_replaced_samples_are_archived_checked_and_shown(tmp_path):
    arch, result, injected = _process(tmp_path, "spiked", spikes=True)
    summary = queries.run_summary(arch, result["run_id"])
    cal = summary.calibration
    counts = cal.step_statistics("solve")["replaced_samples"]["despike"]
    assert set(counts) == set(ROTATION_LABELS)
    for label in ROTATION_LABELS:
        # Spikes in a rotation with the axis's own shaking can hide one another (within
        # 20 samples); never more are replaced than were put in.
        assert 0.5 * injected[label] <= sum(counts[label].values()) <= injected[label], label
    checks = {c.name: c for c in cal.checks}
    for label in ROTATION_LABELS:
        check = checks[f"model:replaced:despike:{label}"]
        assert not check.passed and check.value == sum(counts[label].values())
    # The unit is judged by its parameters (every one in tolerance); the replacements are
    # a finding about the record: "needs review", never "fail".
    assert all(c.passed for c in cal.checks if c.name.startswith("param:"))
    assert cal.verdict == "needs review", [c.name for c in cal.checks if not c.passed]
    views = _views(tmp_path, arch, result)
    for where, text in views.items():
        flat = " ".join(text.split())
        for label in ROTATION_LABELS:  # each count, wherever the verdict is
            total = sum(counts[label].values())
            assert f"model:replaced:despike:{label}" in flat, (where, label)
            assert f"despike replaced {total} of" in flat, (where, label)


def _views(tmp_path: Path, arch, result) -> dict[str, str]:
    """`calib show`, the protocol, the HTML certificate (`calib report`) and the web page
    of a run, as text."""
    from fastapi.testclient import TestClient

    from pipelines.web.app import create_app
    from storage.queries import open_readonly

    run_id = result["run_id"]
    runner = CliRunner()
    shown = runner.invoke(
        app, ["show", run_id, "--archive", str(arch.root)], env={"COLUMNS": "400"}
    )
    assert shown.exit_code == 0, shown.output
    out = tmp_path / "report"
    made = runner.invoke(
        app, ["report", run_id, "--archive", str(arch.root), "--output", str(out), "--no-pdf"]
    )
    assert made.exit_code == 0, made.output
    ro = open_readonly(arch)
    page = TestClient(create_app(ro)).get(f"/runs/{run_id}").text
    ro.dispose()
    return {
        "show": shown.output,
        "protocol": Path(result["protocol"]).read_text(),
        "certificate": next(out.glob("*_certificate.html")).read_text(encoding="utf-8"),
        "web": page,
    }


def test_a_clean_run_replaces_nothing(tmp_path):
    arch, result, _ = _process(tmp_path, "clean", spikes=False)
    cal = queries.run_summary(arch, result["run_id"]).calibration
    counts = cal.step_statistics("solve")["replaced_samples"]["despike"]
    assert all(sum(c.values()) == 0 for c in counts.values()), counts
    assert all(c.passed for c in cal.checks if c.name.startswith("model:replaced:"))
    # The counts (0) are shown all the same, beside the verdict.
    for where, text in _views(tmp_path, arch, result).items():
        assert "despike replaced 0 of" in " ".join(text.split()), where
