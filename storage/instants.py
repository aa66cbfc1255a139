"""The archive's instants: a column type that stores UTC and reads back UTC-aware.

Its own module so that a question reading a few columns (`storage.queries.unit_history`)
types them without building the archive's mapped tables (`storage.schema`).
"""

from __future__ import annotations

from datetime import UTC, datetime

from sqlalchemy.engine import Dialect
from sqlalchemy.types import DateTime, TypeDecorator


class UTCDateTime(TypeDecorator):
    """Timezone-aware datetime stored as UTC and always returned UTC-aware.

    SQLite has no time zone type and gives back naive datetimes even for
    ``DateTime(timezone=True)``; PostgreSQL gives them in the session's zone.
    Naive input is refused, because its meaning (local time? UTC?) is unknown.
    """

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None or value.utcoffset() is None:
            raise ValueError(f"naive datetime {value!r}: the archive needs a time zone")
        value = value.astimezone(UTC)
        return value.replace(tzinfo=None) if dialect.name == "sqlite" else value

    def process_result_value(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)
