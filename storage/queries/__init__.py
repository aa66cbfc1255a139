"""Questions asked of the archive, answered as dicts and pandas DataFrames; one module
per kind of question:

- `runs`: one run's summary, export, the lineage of a value, samples, repeatability group;
- `history`: a unit over time (history, latest and latest valid calibration), units,
  a model's fleet and its history;
- `equipment`: runs made with equipment past its due date;
- `thermal`: thermal models and campaigns;
- `selection`: the runs a reprocessing takes, and current vs. superseded revisions.

Every untrusted input (serial, run id, parameter name, date) is a bound parameter of a
SQLAlchemy statement, never part of a SQL string (`_common`). The public functions are
importable from here: ``from storage import queries; queries.history(...)``.
"""

from storage.queries._common import (
    VERDICTS,
    as_instant,
    check_parameter,
    check_serial,
    check_text,
    check_verdict,
)
from storage.queries.audit import AUDIT_COLUMNS, audit_trail
from storage.queries.equipment import LAPSED_COLUMNS, lapsed_runs
from storage.queries.history import (
    FLEET_COLUMNS,
    HISTORY_COLUMNS,
    LATEST_COLUMNS,
    REVISION_COLUMNS,
    UNIT_COLUMNS,
    fleet,
    fleet_history,
    history,
    history_rows,
    latest_calibration,
    latest_valid,
    parameter_history,
    serial_parameter_history,
    units,
)
from storage.queries.runs import (
    device_description,
    earlier_descriptions,
    export_calibration,
    full_run_id,
    lineage,
    repeatability_candidates,
    run_samples,
    run_summary,
)
from storage.queries.selection import SELECTION_KEYS, revision_pairs, select_runs
from storage.queries.thermal import campaign_calibrations, latest_thermal_model, thermal_models

__all__ = [
    "AUDIT_COLUMNS", "audit_trail", "device_description", "earlier_descriptions",
    "FLEET_COLUMNS", "HISTORY_COLUMNS", "LAPSED_COLUMNS", "LATEST_COLUMNS", "UNIT_COLUMNS",
    "VERDICTS", "as_instant", "campaign_calibrations", "check_parameter", "check_serial",
    "check_text", "check_verdict", "export_calibration", "fleet", "fleet_history",
    "full_run_id", "history", "history_rows", "REVISION_COLUMNS", "lapsed_runs",
    "latest_calibration", "latest_thermal_model",
    "latest_valid", "lineage", "parameter_history", "repeatability_candidates", "run_samples",
    "run_summary", "serial_parameter_history", "thermal_models", "units",
    "SELECTION_KEYS", "revision_pairs", "select_runs",
]  # fmt: skip
