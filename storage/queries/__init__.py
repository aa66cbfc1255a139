"""Questions asked of the archive, answered as dicts and pandas DataFrames; one module
per kind of question:

- `runs`: one run's summary, export, the lineage of a value, samples, repeatability group,
  how a revision was judged;
- `runs_list`: the runs list (filters, sort, pages), its filters' values, the archive's size;
- `unit`: one unit as the browser shows it (device row, parameters, thermal model) and
  the revisions of a run;
- `fleets`: a model's units by their latest run, a parameter over the fleet (derived tables);
- `history`: a unit over time (history, latest and latest valid calibration), units,
  a model's fleet and its history;
- `equipment`: equipment and its due dates, runs made with it past its due date;
- `impact`: the runs that used one piece of equipment in a period (`calib impact`);
- `thermal`: thermal models and campaigns;
- `selection`: the runs a reprocessing takes, and current vs. superseded revisions;
- `readonly`: the archive opened read-only (`open_readonly`).

Which calibration is current, valid or a unit's latest is one rule (storage.current).

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
from storage.queries.equipment import (
    LAPSED_COLUMNS,
    due_state,
    equipment_item,
    equipment_list,
    lapsed_page,
    lapsed_runs,
    today_utc,
)
from storage.queries.fleets import (
    FAILING_MAX,
    FleetUnits,
    fleet_lineage,
    fleet_units,
    fleet_values,
    models,
)
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
from storage.queries.impact import equipment_runs, run_references
from storage.queries.readonly import open_readonly
from storage.queries.runs import (
    current_judgements,
    device_description,
    earlier_descriptions,
    export_calibration,
    full_run_id,
    judgement,
    lineage,
    repeatability_candidates,
    run_samples,
    run_summary,
)
from storage.queries.runs_list import (
    MAX_PAGE,
    PER_PAGE,
    SORTS,
    RunFilter,
    RunsPage,
    choices,
    facts,
    run_filter,
    runs_page,
)
from storage.queries.selection import SELECTION_KEYS, revision_pairs, select_runs
from storage.queries.thermal import campaign_calibrations, latest_thermal_model, thermal_models
from storage.queries.unit import device, revisions, thermal_model, unit_parameters

__all__ = [
    "AUDIT_COLUMNS",
    "audit_trail",
    "device_description",
    "earlier_descriptions",
    "FLEET_COLUMNS",
    "HISTORY_COLUMNS",
    "LAPSED_COLUMNS",
    "LATEST_COLUMNS",
    "UNIT_COLUMNS",
    "VERDICTS",
    "as_instant",
    "campaign_calibrations",
    "check_parameter",
    "current_judgements",
    "check_serial",
    "check_text",
    "check_verdict",
    "export_calibration",
    "fleet",
    "fleet_history",
    "full_run_id",
    "history",
    "history_rows",
    "REVISION_COLUMNS",
    "judgement",
    "lapsed_runs",
    "latest_calibration",
    "latest_thermal_model",
    "latest_valid",
    "lineage",
    "parameter_history",
    "repeatability_candidates",
    "run_samples",
    "run_summary",
    "serial_parameter_history",
    "thermal_models",
    "units",
    "SELECTION_KEYS",
    "revision_pairs",
    "select_runs",
    "equipment_runs",
    "run_references",
    "due_state",
    "equipment_item",
    "equipment_list",
    "lapsed_page",
    "today_utc",
    "FAILING_MAX",
    "FleetUnits",
    "fleet_lineage",
    "fleet_units",
    "fleet_values",
    "models",
    "open_readonly",
    "MAX_PAGE",
    "PER_PAGE",
    "SORTS",
    "RunFilter",
    "RunsPage",
    "choices",
    "facts",
    "run_filter",
    "runs_page",
    "device",
    "revisions",
    "thermal_model",
    "unit_parameters",
]
