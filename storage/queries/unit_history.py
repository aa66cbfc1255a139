"""A unit's calibration revisions (`history`), read from light table clauses.

`calib history` is asked often and answers a small question; these columns of
storage.schema's tables, named here with their types, give it without building the
archive's mapped tables (tests/test_cli_imports.py checks them against storage.schema).
The serial is a bound parameter, as in every question.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from sqlalchemy import column, select, table

from storage.current import superseded
from storage.db import Archive
from storage.instants import UTCDateTime

if TYPE_CHECKING:
    import pandas as pd  # imported where a frame is made (slow to import)

DEVICES = table("devices", column("id"), column("serial"))
RUNS = table(
    "runs",
    column("id"),
    column("device_id"),
    column("run_id"),
    column("started_at", UTCDateTime),
    column("procedure"),
)
CALIBRATIONS = table(
    "calibrations",
    column("run_id"),
    column("revision"),
    column("verdict"),
    column("superseded_by"),
    column("software_version"),
    column("created_at", UTCDateTime),
)

REVISION_COLUMNS = [
    "run_id",
    "started_at",
    "procedure",
    "revision",
    "verdict",
    "superseded",
    "software_version",
    "created_at",
]


def history_rows(archive: Archive, serial: str) -> list[dict[str, Any]]:
    """`history` as dicts (keys `REVISION_COLUMNS`), without pandas: what a table printed
    at the terminal needs, so `calib history` starts without loading pandas."""
    run, cal, dev = RUNS.c, CALIBRATIONS.c, DEVICES.c
    stmt = (
        select(
            run.run_id,
            run.started_at,
            run.procedure,
            cal.revision,
            cal.verdict,
            superseded(CALIBRATIONS).label("superseded"),
            cal.software_version,
            cal.created_at,
        )
        .select_from(RUNS)
        .join(DEVICES, dev.id == run.device_id)
        .join(CALIBRATIONS, cal.run_id == run.id)
        .where(dev.serial == serial)
        .order_by(run.started_at, run.id, cal.revision)
    )
    with archive.engine().connect() as conn:
        rows = conn.execute(stmt).all()
    return [
        {**dict(zip(REVISION_COLUMNS, r, strict=True)), "superseded": bool(r.superseded)}
        for r in rows
    ]


def history(archive: Archive, serial: str) -> pd.DataFrame:
    """One row per calibration revision of a unit, oldest run first.

    Parameters
    ----------
    archive : the archive.
    serial : the unit.

    Returns
    -------
    DataFrame with columns run_id, started_at, procedure, revision, verdict,
    superseded, software_version, created_at.
    """
    import pandas as pd

    df = pd.DataFrame(history_rows(archive, serial), columns=REVISION_COLUMNS)
    return df.astype({"superseded": bool})
