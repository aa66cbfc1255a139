"""The settings hash of a calibration: what decides its result besides the raw bytes.

A light module (hashlib and json only) so that `calib verify` recomputes hashes without
loading the write side of the archive.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

# The setting of a `rejudge` step (sealed with the revision): run ids of the unit's runs
# made before the run, most recent first, that the revision was judged against.
JUDGED_AGAINST = "judged_against"
REJUDGE_STEP = "rejudge"


def settings_hash(
    settings: dict[str, Any],
    procedure: str,
    profile_name: str | None,
    profile_version: str | None,
    judged_against: list[str] | None = None,
) -> str:
    """The settings hash of a calibration (`settings_hash_of`) from its parts.

    `judged_against` : for a revision judged again (`rejudge_run`), the run ids its
    ``rejudge`` step records under `JUDGED_AGAINST`: the same settings judged against
    other runs are another calibration. None (not part of the hash) for a processing.
    """
    doc = {
        "settings": settings,
        "procedure": procedure,
        "profile_name": profile_name,
        "profile_version": profile_version,
    }
    if judged_against is not None:
        doc[JUDGED_AGAINST] = judged_against
    return hashlib.sha256(canonical_json(doc, "settings").encode()).hexdigest()


def canonical_json(value: Any, where: str) -> str:
    """Sorted-key, compact JSON; ValueError naming `where` for a value JSON cannot hold."""
    try:
        return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: not storable as JSON ({exc})") from exc
