"""The certificate's recommended recalibration interval (pipelines.reports.recommendations)
in words a reader takes in: months, or days when under a month (a unit that drifts fast),
never "0 months". The recall rows are made by pipelines.recall's own row maker."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest

from pipelines.recall import DAYS_PER_MONTH, _entry
from pipelines.reports.recommendations import interval_text
from pipelines.tolerances import load_profile

LAST = {"verdict": "pass", "started_at": datetime(2026, 11, 2, 9, tzinfo=UTC), "run_id": "R1"}


def _recall(days: float) -> dict:
    limited = {"days": days, "parameter": "gyr.bias.x", "capped": False}
    return _entry("FAST-1", "MPU-6000", load_profile("mpu6000"), limited, LAST, None)


@pytest.mark.parametrize(
    ("days", "words"),
    [
        (9.0, "9 days, by 2026-11-11"),
        (1.2, "1 day, by 2026-11-03"),
        (0.4, "0.4 days, by 2026-11-02"),
        (29.0, "29 days, by 2026-12-01"),
        (DAYS_PER_MONTH, "1 month, by 2026-12-02"),
        (400.0, "13.1 months, by 2027-12-07"),
    ],
)
def test_a_short_interval_is_given_in_days(days: float, words: str) -> None:
    text = interval_text(_recall(days))
    assert text.startswith(words + " ("), text
    assert "0 months" not in text and "probability 95% of gyr.bias.x" in text


def test_the_default_interval_stays_in_months() -> None:
    assert interval_text(None) == "12 months"
