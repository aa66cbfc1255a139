"""One lab run from its files to the archive: ingest, preprocess, solve, check, archive.

Each stage is a plain function; `process_run` strings them together and turns
any error into a failed outcome (nothing archived) so a batch goes on. The
Prefect flows in `pipelines.flows` wrap `process_run` and nothing else.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import Any

import numpy as np
import pyarrow as pa

from calib_core import procedures
from calib_core.calibration import Calibration, CheckResult, StepRecord
from calib_core.checks import check_parameters, check_residuals, verdict
from calib_core.preprocess.outliers import remove_outliers
from calib_core.recording import Recording
from pipelines.ingest import LoadedRun, RunSource, load_run
from pipelines.ingest.errors import IngestError
from pipelines.provenance import SOFTWARE_VERSION, source_revision
from pipelines.reports.protocol import render_protocol
from pipelines.tolerances import load_profile
from storage.archive import ArchiveResult, RawFileIn, RunIn, archive_run, raw_hash_of, run_id_of
from storage.db import Archive

log = logging.getLogger("calib.process")

DEFAULT_OUTLIERS = {"method": "sigma", "n_sigma": 3.0, "policy": "interpolate"}


def is_static(label: str) -> bool:
    """Static positions are labelled `<axis>_up` / `<axis>_dn`."""
    return label.endswith(("_up", "_dn"))


def preprocess(
    segments: dict[str, Recording], settings: dict[str, Any]
) -> tuple[dict[str, Recording], list[StepRecord]]:
    """Outlier removal on the static segments (never across a rotation, where the signal moves).

    settings["outliers"] overrides DEFAULT_OUTLIERS; ``{"method": "none"}`` turns it off.
    """
    cfg = {**DEFAULT_OUTLIERS, **settings.get("outliers", {})}
    if cfg["method"] == "none":
        return segments, [StepRecord("outliers", settings=cfg, statistics={"skipped": True})]
    kwargs = {k: v for k, v in cfg.items() if k != "method"}
    cleaned: dict[str, Recording] = {}
    per_segment: dict[str, Any] = {}
    for label, rec in segments.items():
        if not is_static(label):
            cleaned[label] = rec
            continue
        cleaned[label], record = remove_outliers(rec, method=cfg["method"], **kwargs)
        per_segment[label] = record.statistics
    return cleaned, [StepRecord("outliers", settings=cfg, statistics={"segments": per_segment})]


def samples_table(segments: dict[str, Recording]) -> pa.Table:
    """All segments' samples as one Arrow table (segment, t, acc_*, gyr_*, temp), SI units."""
    cols: dict[str, list[np.ndarray]] = {
        k: []
        for k in ("segment", "t", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z", "temp")
    }
    for label, rec in segments.items():
        n = len(rec)
        cols["segment"].append(np.full(n, label, dtype=object))
        cols["t"].append(rec.t)
        for i, a in enumerate("xyz"):
            cols[f"acc_{a}"].append(rec.acc[:, i])
            cols[f"gyr_{a}"].append(rec.gyr[:, i])
        cols["temp"].append(np.full(n, np.nan) if rec.temp is None else rec.temp)
    return pa.table({k: np.concatenate(v) if v else np.array([]) for k, v in cols.items()})


def _check_dicts(checks: list[CheckResult]) -> list[dict[str, Any]]:
    return [dataclasses.asdict(c) for c in checks]


def run_outcome(
    *,
    source: str,
    serial: str,
    status: str,
    run_id: str = "",
    error: str | None = None,
    cal: Calibration | None = None,
    checks: list[CheckResult] | None = None,
    protocol: str | None = None,
    verdict_: str | None = None,
    message: str | None = None,
) -> dict[str, Any]:
    """One entry of the `calib process --json` document (docs/cli.md)."""
    return {
        "run_id": run_id,
        "serial": serial,
        "status": status,
        "error": error,
        "parameters": {}
        if cal is None
        else {
            n: {"value": p.value, "std": p.std, "unit": p.unit}
            for n, p in sorted(cal.parameters.items())
        },
        "checks": [
            {"name": c.name, "value": c.value, "limit": c.limit, "passed": c.passed}
            for c in (checks or [])
        ],
        "protocol": protocol,
        "verdict": verdict_,
        "source": source,
        "message": message,
    }


def solve_loaded(loaded: LoadedRun) -> tuple[Calibration, list[StepRecord], dict[str, Any]]:
    """Preprocess and solve a loaded run; returns the calibration, step records and settings."""
    m = loaded.manifest
    settings = dict(m.run.settings)
    segments, steps = preprocess(loaded.segments, settings)
    started = time.perf_counter()
    cal = procedures.solve(m.run.procedure, segments, m.gravity(), settings)
    steps.append(
        StepRecord(
            "solve",
            settings={"procedure": m.run.procedure, **settings},
            statistics={
                "seconds": round(time.perf_counter() - started, 4),
                "parameters": len(cal.parameters),
                "warnings": list(cal.warnings),
                **{k: v for k, v in cal.info.items() if isinstance(v, int | float | str)},
            },
        )
    )
    return cal, steps, settings


def process_run(source: RunSource, archive: Archive) -> dict[str, Any]:
    """Ingest, preprocess, solve, check and archive one run. Never raises for bad input.

    Returns the run's entry of the `calib process --json` document.
    """
    where = str(source.folder)
    serial = source.serial or ""
    try:
        loaded = load_run(source)
        m = loaded.manifest
        serial = m.unit.serial
        ingest_step = StepRecord(
            "ingest",
            settings={"format": m.format.model_dump(mode="json")},
            statistics={
                "files": len(loaded.raw_files),
                "samples": {k: len(r) for k, r in loaded.segments.items()},
            },
        )
        cal, steps, settings = solve_loaded(loaded)
        steps.insert(0, ingest_step)
        profile = load_profile(m.run.tolerance_profile)
        checks = check_parameters(cal, profile) + check_residuals(cal, profile)
        verdict_ = verdict(checks)
        steps.append(
            StepRecord(
                "check",
                settings={"profile": profile.name, "profile_version": profile.version},
                statistics={
                    "checks": len(checks),
                    "failed": sum(not c.passed for c in checks),
                    "verdict": verdict_,
                },
            )
        )
        run_id = run_id_of(raw_hash_of([f.sha256 for f in loaded.raw_files]))
        params = [
            {
                "name": p.name,
                "value": p.value,
                "std": p.std,
                "unit": p.unit,
                "temperature_c": m.environment.temperature_c,
            }
            for p in sorted(cal.parameters.values(), key=lambda p: p.name)
        ]
        protocol_name = f"{serial}_result.txt"
        protocol_text = render_protocol(
            device_model=m.unit.model,
            serial=serial,
            started_at=m.run.started,
            run_id=run_id,
            procedure=m.run.procedure,
            profile=f"{profile.name} v{profile.version}",
            gravity=cal.gravity,
            operator=m.run.operator,
            parameters=params,
            checks=_check_dicts(checks),
            verdict=verdict_,
        )
        result: ArchiveResult = archive_run(
            archive,
            RunIn(
                serial=serial,
                device_model=m.unit.model,
                manufacturer=m.unit.manufacturer,
                specification=m.unit.specification,
                started_at=m.run.started,
                operator=m.run.operator,
                procedure=m.run.procedure,
                site=m.site.model_dump(mode="json"),
                gravity=cal.gravity,
                environment=m.environment.model_dump(mode="json"),
                equipment=[e.model_dump(mode="json") for e in m.equipment],
                manifest_text=loaded.manifest_text,
                tolerance_profile=profile.name,
                raw_files=[
                    RawFileIn(f.path, f.name, f.sha256, f.size, f.format) for f in loaded.raw_files
                ],
                settings=settings,
                software_version=SOFTWARE_VERSION,
                source_revision=source_revision(),
                steps=[dataclasses.asdict(s) for s in steps],
                calibration=cal.to_dict(),
                parameters=params,
                checks=_check_dicts(checks),
                verdict=verdict_,
                profile_name=profile.name,
                profile_version=profile.version,
                samples=samples_table(loaded.segments),
            ),
            extra_files={protocol_name: protocol_text.encode()},
        )
    except (IngestError, ValueError, OSError) as exc:
        log.warning("run %s failed: %s", where, exc)
        return run_outcome(source=where, serial=serial, status="failed", error=str(exc))
    except Exception as exc:  # a bug must not stop the batch; the traceback goes to the log
        log.exception("run %s failed with an internal error", where)
        return run_outcome(
            source=where,
            serial=serial,
            status="failed",
            error=f"internal error ({type(exc).__name__}): {exc}",
        )
    status = "duplicate" if result.status == "duplicate" else "ok"
    protocol_path = result.files.get(protocol_name)
    return run_outcome(
        source=where,
        serial=serial,
        status=status,
        run_id=result.run_id,
        cal=cal,
        checks=checks,
        protocol=None if protocol_path is None else str(protocol_path),
        verdict_=verdict_,
        message=result.message,
    )
