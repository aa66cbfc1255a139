"""Queries of the archive: input validation and helpers shared by the question modules.

Every untrusted input (serial, run id, parameter name, date) is checked here and then
bound as a parameter of a SQLAlchemy statement, never part of a SQL string.
"""

from __future__ import annotations

import math
from datetime import UTC, date, datetime, time
from typing import TYPE_CHECKING, Any

from sqlalchemy import Connection, Row, Select, bindparam, func, select
from sqlalchemy.orm import Session

from calib_core import params
from storage.current import PASS  # noqa: F401 - the verdict the questions call valid
from storage.naming import check_safe_name
from storage.schema import CalibrationRow, Device, ParameterRow, Run

if TYPE_CHECKING:
    import pandas as pd  # imported where a frame is made (slow to import)

    from storage.db import Archive


# A parameter's value as every question reports it: value and standard uncertainty (SI),
# unit, and the temperature it belongs to (deg C; None for a value without one).
PARAMETER_VALUE = (
    ParameterRow.value, ParameterRow.std, ParameterRow.unit, ParameterRow.temperature_c,
)  # fmt: skip
# Join condition: the row of parameter :name (bound at execution) of the calibration joined.
NAMED_PARAMETER = (ParameterRow.calibration_id == CalibrationRow.id) & (
    ParameterRow.name == bindparam("name")
)


def reading(archive: Archive) -> Connection:
    """A connection to ask the archive a question (``with reading(archive) as conn``).

    On PostgreSQL in autocommit: no BEGIN and ROLLBACK around the statements, two round
    trips fewer per question, which a busy machine makes cost more than the index lookups
    themselves. The answers are the same: under READ COMMITTED (PostgreSQL's default,
    which the archive keeps) each statement sees what was committed before it began,
    inside a transaction or not, and a question writes nothing. SQLite keeps its read
    transaction: one snapshot for all statements of a question.
    """
    conn = archive.engine().connect()
    return conn if archive.is_sqlite else conn.execution_options(isolation_level="AUTOCOMMIT")


def select_run_calibrations(*columns: Any) -> Select:
    """``select(*columns)`` over the runs joined to their unit (Device) and to every
    calibration revision of theirs (`storage.current.CURRENT` picks the current ones)."""
    return (
        select(*columns)
        .select_from(Run)
        .join(Device, Device.id == Run.device_id)
        .join(CalibrationRow, CalibrationRow.run_id == Run.id)
    )


def _dict(row: Row) -> dict[str, Any]:
    return dict(row._mapping)


IN_CHUNK = 500  # ids bound per statement (well below SQLite's and PostgreSQL's limits)


def parameter_values(s: Session, cal_ids: list[int]) -> dict[int, dict[str, tuple]]:
    """{calibration id: {parameter name: (value, std)}} of `cal_ids`, SI, one query per
    IN_CHUNK ids; of a name with rows at several temperatures, the last row written."""
    values: dict[int, dict[str, tuple]] = {i: {} for i in cal_ids}
    for start in range(0, len(cal_ids), IN_CHUNK):
        for cal_id, name, value, std in s.execute(
            select(
                ParameterRow.calibration_id, ParameterRow.name, ParameterRow.value, ParameterRow.std
            )
            .where(ParameterRow.calibration_id.in_(cal_ids[start : start + IN_CHUNK]))
            .order_by(ParameterRow.id)
        ):
            values[cal_id][name] = (value, std)
    return values


# --- traceability, equipment validity, units, fleet ----------------------------------
#
# The functions below validate their filters (a clear ValueError naming the
# filter) before any SQL runs, and bind every value. Dates given as `date` mean
# whole UTC days: `as_of`/`date_to` include the whole day, `date_from` starts at
# its midnight.

VERDICTS = ("pass", "fail", "needs review")  # calib_core.checks.overall_verdict
EQUIPMENT_SERIAL_LEN = 200


def check_serial(serial: str) -> str:
    """A unit serial as the archive stores it (storage.naming rules), else ValueError."""
    return check_safe_name(serial, "serial")


def check_parameter(name: str) -> str:
    """A canonical parameter name (calib_core.params), else ValueError naming it."""
    if not isinstance(name, str):
        raise ValueError(f"parameter: expected a canonical name like 'acc.bias.x', got {name!r}")
    return params.validate(name)


def check_verdict(verdict: str) -> str:
    if verdict not in VERDICTS:
        raise ValueError(f"verdict: expected one of {', '.join(VERDICTS)}, got {verdict!r}")
    return verdict


def check_text(value: str, what: str, max_len: int = 200) -> str:
    """A free-text filter (model, equipment serial): non-empty printable, bounded length."""
    if not isinstance(value, str) or not value or len(value) > max_len or not value.isprintable():
        raise ValueError(f"{what}: expected 1-{max_len} printable characters, got {value!r}")
    return value


def as_instant(
    value: date | datetime | str | None, what: str, *, end_of_day: bool
) -> datetime | None:
    """A time-zone-aware UTC instant from a date, an aware datetime or ISO 8601 text.

    A bare date (``2024-05-01``) means the start of that UTC day, or with
    `end_of_day` its last microsecond, so ``--to 2024-05-01`` includes the day.
    """
    if value is None:
        return None
    if isinstance(value, str):
        text_ = value.strip()
        try:
            value = (
                date.fromisoformat(text_)
                if len(text_) == 10
                else datetime.fromisoformat(text_.replace("Z", "+00:00"))
            )
        except ValueError:
            raise ValueError(
                f"{what}: expected a date YYYY-MM-DD or a date-time with a zone "
                f"(2024-05-01T08:30:00+00:00), got {value!r}"
            ) from None
    if isinstance(value, datetime):
        if value.utcoffset() is None:
            raise ValueError(f"{what}: {value.isoformat()} has no time zone (add +00:00 or Z)")
        return value.astimezone(UTC)
    if isinstance(value, date):
        t = datetime.combine(value, time.max if end_of_day else time.min, tzinfo=UTC)
        return t
    raise ValueError(f"{what}: expected a date or datetime, got {type(value).__name__}")


def _finite(value: float | None, what: str) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{what}: expected a finite number, got {value!r}")
    return float(value)


def _run_day(dialect: str):  # noqa: ANN202 - a SQL expression
    """The UTC calendar day a run started, as a SQL date on either back end."""
    if dialect == "postgresql":
        return func.date(func.timezone("UTC", Run.started_at))
    return func.date(Run.started_at)  # SQLite keeps naive UTC text


def where_model_and_start(stmt, model: str | None, t0: datetime | None, t1: datetime | None):  # noqa: ANN001, ANN201 - a select
    """`stmt` (over Run joined to Device) limited to a device model and a run start range."""
    if model is not None:
        stmt = stmt.where(Device.model == check_text(model, "model"))
    if t0 is not None:
        stmt = stmt.where(Run.started_at >= t0)
    if t1 is not None:
        stmt = stmt.where(Run.started_at <= t1)
    return stmt


def _frame(rows: list[Row | tuple], columns: list[str]) -> pd.DataFrame:
    import pandas as pd

    return pd.DataFrame.from_records([tuple(r) for r in rows], columns=columns)


# far future: "as of now" for the latest-valid questions
_FOREVER = datetime(9999, 12, 31, tzinfo=UTC)
