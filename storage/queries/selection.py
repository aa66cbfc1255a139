"""Queries of the archive about a selection of runs: which runs a reprocessing takes, and
each run's current calibration beside the revision it superseded (the change report).
"""

from __future__ import annotations

from datetime import date, datetime
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session, aliased

from storage.current import current, is_current
from storage.db import Archive
from storage.queries._common import (
    IN_CHUNK,
    as_instant,
    check_serial,
    check_text,
    parameter_values,
    where_model_and_start,
)
from storage.schema import AuditEvent, CalibrationRow, Device, Run

SELECTION_KEYS = ("serial", "model", "since", "until", "software_version", "profile")


def select_runs(
    archive: Archive,
    *,
    serial: str | None = None,
    model: str | None = None,
    since: date | datetime | str | None = None,
    until: date | datetime | str | None = None,
    software_version: str | None = None,
    profile: str | None = None,
) -> list[dict[str, Any]]:
    """The archived runs matching every filter given (none: all), oldest run first.

    Parameters
    ----------
    serial, model : the unit's serial, its device model.
    since, until : run start, inclusive (dates are whole UTC days).
    software_version, profile : of the run's current calibration (the software that
        made it, the tolerance profile name it was judged by).

    Returns
    -------
    list of dicts: run_id, serial, procedure, started_at, and ``calibrations``, every
    revision of the run as dicts (revision, settings_hash, settings, software_version,
    profile_name, current), oldest first.

    Raises ValueError naming the filter for a malformed value, before any SQL runs.
    """
    t0 = as_instant(since, "since", end_of_day=False)
    t1 = as_instant(until, "until", end_of_day=True)
    cal = aliased(CalibrationRow)
    stmt = (
        select(Run.id, Run.run_id, Device.serial, Run.procedure, Run.started_at)
        .join(Device, Device.id == Run.device_id)
        .join(cal, (cal.run_id == Run.id) & current(cal))
        .order_by(Run.started_at, Run.run_id)
    )
    if serial is not None:
        stmt = stmt.where(Device.serial == check_serial(serial))
    stmt = where_model_and_start(stmt, model, t0, t1)
    if software_version is not None:
        stmt = stmt.where(cal.software_version == check_text(software_version, "software version"))
    if profile is not None:
        stmt = stmt.where(cal.profile_name == check_text(profile, "profile"))
    with Session(archive.engine()) as s:
        runs = s.execute(stmt).all()
        cals: dict[int, list[dict[str, Any]]] = {r.id: [] for r in runs}
        ids = list(cals)
        for start in range(0, len(ids), IN_CHUNK):
            rows = s.execute(
                select(
                    CalibrationRow.run_id,
                    CalibrationRow.revision,
                    CalibrationRow.settings_hash,
                    CalibrationRow.settings,
                    CalibrationRow.software_version,
                    CalibrationRow.profile_name,
                    CalibrationRow.verdict,
                    CalibrationRow.superseded_by,
                )
                .where(CalibrationRow.run_id.in_(ids[start : start + IN_CHUNK]))
                .order_by(CalibrationRow.run_id, CalibrationRow.revision)
            ).all()
            for c in rows:
                cals[c.run_id].append(
                    {
                        "revision": c.revision,
                        "settings_hash": c.settings_hash,
                        "settings": c.settings,
                        "software_version": c.software_version,
                        "profile_name": c.profile_name,
                        "verdict": c.verdict,
                        "current": is_current(c.superseded_by),
                    }
                )
    return [
        {
            "run_id": r.run_id,
            "serial": r.serial,
            "procedure": r.procedure,
            "started_at": r.started_at,
            "calibrations": cals[r.id],
        }
        for r in runs
    ]


def revision_pairs(archive: Archive, run_ids: list[str]) -> list[dict[str, Any]]:
    """Each run's current calibration and the revision it superseded, for the change report.

    Runs whose current calibration superseded none (revision 1 only) are left out.

    Returns
    -------
    list of dicts, in the order of `run_ids`: run_id, serial, and ``new`` / ``old``
    each with revision, software_version, profile_name, profile_version, verdict and
    parameters (canonical name -> (value, std), SI).
    """
    new, old = aliased(CalibrationRow), aliased(CalibrationRow)
    found: dict[str, dict[str, Any]] = {}
    with Session(archive.engine()) as s:
        for start in range(0, len(run_ids), IN_CHUNK):
            stmt = (
                select(Run.run_id, Device.serial, new, old)
                .join(Device, Device.id == Run.device_id)
                .join(new, (new.run_id == Run.id) & current(new))
                .join(old, old.superseded_by == new.id)
                .where(Run.run_id.in_(run_ids[start : start + IN_CHUNK]))
            )
            for row in s.execute(stmt).all():
                found[row.run_id] = {
                    "run_id": row.run_id,
                    "serial": row.serial,
                    "new": row[2],
                    "old": row[3],
                }
        values = parameter_values(s, [c.id for p in found.values() for c in (p["new"], p["old"])])
        return [
            {
                **found[r],
                "new": _revision(found[r]["new"], values),
                "old": _revision(found[r]["old"], values),
            }
            for r in run_ids
            if r in found
        ]


def revised_for(archive: Archive, run_ids: list[str], reason: str) -> set[tuple[str, int]]:
    """(run id, revision) of the revisions of `run_ids` archived with `reason` (their
    ``revised`` event's): what an earlier pass of the same reprocessing revised."""
    found: set[tuple[str, int]] = set()
    with archive.engine().connect() as conn:
        for start in range(0, len(run_ids), IN_CHUNK):
            rows = conn.execute(
                select(AuditEvent.run_id, AuditEvent.revision).where(
                    AuditEvent.action == "revised",
                    AuditEvent.reason == reason,
                    AuditEvent.run_id.in_(run_ids[start : start + IN_CHUNK]),
                )
            )
            found |= {(run_id, rev) for run_id, rev in rows}
    return found


def _revision(cal: CalibrationRow, values: dict[int, dict]) -> dict[str, Any]:
    return {
        "revision": cal.revision,
        "software_version": cal.software_version,
        "profile_name": cal.profile_name,
        "profile_version": cal.profile_version,
        "verdict": cal.verdict,
        "parameters": values[cal.id],
    }
