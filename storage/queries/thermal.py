"""Thermal compensation, the archive queries: thermal models, campaigns, drift histories.

Campaign queries read *current* revisions (not superseded) of any verdict: a unit at
-10 deg C may well fail its room-temperature tolerance and still be a valid point of
its thermal curve.
"""

from __future__ import annotations

from datetime import datetime
from typing import TYPE_CHECKING, Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from storage.current import CURRENT, is_current, superseded
from storage.db import Archive
from storage.queries._common import select_run_calibrations
from storage.schema import (
    CalibrationRow,
    Device,
    Run,
    ThermalModelRow,
)

if TYPE_CHECKING:
    import pandas as pd  # imported where a frame is made (slow to import)


def device_pk(s: Session, serial: str) -> int:
    """The id of the unit `serial`'s device row (LookupError if none)."""
    dev = s.execute(select(Device.id).where(Device.serial == serial)).scalar_one_or_none()
    if dev is None:
        raise LookupError(f"no device with serial {serial!r} in the archive")
    return dev


def _model_dict(row: ThermalModelRow, serial: str, s: Session) -> dict[str, Any]:
    ids = list(row.calibration_ids)
    fitted = {
        cal_id: {"run_id": run_id, "revision": revision}
        for cal_id, run_id, revision in s.execute(
            select(CalibrationRow.id, Run.run_id, CalibrationRow.revision)
            .join(Run, Run.id == CalibrationRow.run_id)
            .where(CalibrationRow.id.in_(ids))
        )
    }
    return {
        "id": row.id,
        "serial": serial,
        "created_at": row.created_at,
        "model_name": row.model_name,
        "model_version": row.model_version,
        "t_ref": row.t_ref,
        "t_min": row.t_min,
        "t_max": row.t_max,
        "calibration_ids": ids,
        # the runs (and revisions) of those calibrations, in their order
        "runs": [fitted[i] for i in ids if i in fitted],
        "superseded_by": row.superseded_by,
        "document": row.document,
    }


def latest_thermal_model(
    archive: Archive, serial: str, as_of: datetime | None = None
) -> dict[str, Any] | None:
    """The current thermal model of `serial` created at or before `as_of` (None: now).

    Returns None when there is none, else a dict with the row's fields and
    ``document`` (the ThermalModel JSON).
    """
    if as_of is not None and as_of.utcoffset() is None:
        raise ValueError(f"as_of: expected a time-zone-aware datetime, got {as_of!r}")
    with Session(archive.engine()) as s:
        stmt = (
            select(ThermalModelRow)
            .join(Device, Device.id == ThermalModelRow.device_id)
            .where(Device.serial == serial)
            .order_by(superseded(ThermalModelRow), ThermalModelRow.id.desc())
        )
        if as_of is not None:
            stmt = stmt.where(ThermalModelRow.created_at <= as_of)
        rows = s.execute(stmt).scalars().all()
        if not rows:
            return None
        # Newest not superseded by a model that already existed at as_of.
        then = {r.id for r in rows}
        current = [r for r in rows if is_current(r.superseded_by) or r.superseded_by not in then]
        return _model_dict(max(current, key=lambda r: r.id), serial, s)


def thermal_models(archive: Archive, serial: str) -> pd.DataFrame:
    """Every thermal model of a unit, oldest first (without the JSON document)."""
    import pandas as pd

    cols = [
        "id",
        "created_at",
        "model_name",
        "model_version",
        "t_ref",
        "t_min",
        "t_max",
        "calibration_ids",
        "superseded_by",
    ]
    with Session(archive.engine()) as s:
        rows = s.execute(
            select(*(getattr(ThermalModelRow, c) for c in cols))
            .join(Device, Device.id == ThermalModelRow.device_id)
            .where(Device.serial == serial)
            .order_by(ThermalModelRow.id)
        ).all()
    return pd.DataFrame(rows, columns=cols)


def campaign_calibrations(
    archive: Archive, serial: str, run_ids: list[str] | None = None
) -> list[dict[str, Any]]:
    """Current calibrations of a unit with their run's temperature, oldest run first.

    Each dict: calibration_id, run_id, started_at, temperature_c (the run
    manifest's environment.temperature_c, None if not given), verdict, document
    (Calibration.to_dict()).

    Raises LookupError for an unknown serial or run id of another unit.
    """
    with Session(archive.engine()) as s:
        device_pk(s, serial)
        stmt = (
            select_run_calibrations(
                CalibrationRow.id,
                Run.run_id,
                Run.started_at,
                Run.environment,
                CalibrationRow.verdict,
                CalibrationRow.document,
            )
            .where(Device.serial == serial, CURRENT)
            .order_by(Run.started_at, Run.id)
        )
        if run_ids:
            stmt = stmt.where(Run.run_id.in_(run_ids))
        rows = s.execute(stmt).all()
    if run_ids:
        missing = sorted(set(run_ids) - {r.run_id for r in rows})
        if missing:
            raise LookupError(f"runs {missing} are not archived runs of {serial!r}")
    return [
        {
            "calibration_id": r.id,
            "run_id": r.run_id,
            "started_at": r.started_at,
            "temperature_c": (r.environment or {}).get("temperature_c"),
            "verdict": r.verdict,
            "document": r.document,
        }
        for r in rows
    ]
