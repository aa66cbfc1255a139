"""Thermal compensation, the archive: writing a fitted model (table thermal_models).

A thermal model (calib_core.thermal.ThermalModel.to_dict) is fitted from
several calibrations of one device. Archiving a new model of a device sets
`superseded_by` on its current one, as re-processing does for calibrations; the
list of calibration ids it was fitted from keeps it traceable to raw files.
Reading models and campaigns: storage.queries.thermal.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from storage import seal
from storage.current import current
from storage.db import Archive
from storage.queries.thermal import device_pk
from storage.schema import CalibrationRow, Run, ThermalModelRow


def archive_thermal_model(
    archive: Archive,
    serial: str,
    document: dict[str, Any],
    calibration_ids: list[int],
) -> int:
    """Store a thermal model of `serial`; it supersedes the device's current model.

    Parameters
    ----------
    document : ThermalModel.to_dict() (model, schema_version, t_ref, t_min, t_max...).
    calibration_ids : archive ids of the calibrations it was fitted from.

    Returns
    -------
    The new row's id.
    """
    for key in ("model", "schema_version", "t_ref", "t_min", "t_max"):
        if key not in document:
            raise ValueError(f"thermal model document lacks {key!r}")
    if not calibration_ids:
        raise ValueError("a thermal model must name the calibrations it was fitted from")
    # SQLite: the write lock at BEGIN (the audit chain is read and appended to).
    with Session(archive.engine().execution_options(sqlite_begin="IMMEDIATE")) as s, s.begin():
        device_id = device_pk(s, serial)
        known = set(
            s.execute(
                select(CalibrationRow.id)
                .join(Run, Run.id == CalibrationRow.run_id)
                .where(CalibrationRow.id.in_(calibration_ids), Run.device_id == device_id)
            ).scalars()
        )
        missing = sorted(set(calibration_ids) - known)
        if missing:
            raise ValueError(f"calibration ids {missing} are not calibrations of {serial!r}")
        row = ThermalModelRow(
            device_id=device_id,
            model_name=str(document["model"]),
            model_version=str(document["schema_version"]),
            t_ref=float(document["t_ref"]),
            t_min=float(document["t_min"]),
            t_max=float(document["t_max"]),
            document=document,
            calibration_ids=sorted(int(i) for i in calibration_ids),
        )
        s.add(row)
        s.flush()
        for old in s.execute(
            select(ThermalModelRow).where(
                ThermalModelRow.device_id == device_id,
                current(ThermalModelRow),
                ThermalModelRow.id != row.id,
            )
        ).scalars():
            old.superseded_by = row.id
        s.flush()
        seal.append_event(
            s.connection(),
            "thermal model",
            detail={
                "serial": serial,
                "thermal_model_id": row.id,
                "model": row.model_name,
                "calibration_ids": row.calibration_ids,
            },
        )
        return row.id
