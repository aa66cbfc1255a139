"""Questions asked of the archive, answered as typed records (`records`: a run's summary
and a revision, frozen dataclasses), dicts and pandas DataFrames; one module per kind of
question:

- `runs`: one run's summary, export, the lineage of a value, samples, repeatability group,
  how a revision was judged;
- `runs_list`: the runs list (filters, sort, pages), its filters' values, the archive's size;
- `unit`: one unit as the browser shows it (device row, parameters, thermal model) and
  the revisions of a run;
- `fleets`: a model's units by their latest run, a parameter over the fleet (derived tables);
- `history`: a unit over time (history, latest run, latest and latest valid calibration), units,
  a model's fleet and its history;
- `equipment`: equipment and its due dates, runs made with it past its due date;
- `impact`: the runs that used one piece of equipment in a period (`calib impact`);
- `thermal`: thermal models and campaigns;
- `selection`: the runs a reprocessing takes, and current vs. superseded revisions;
- `audit`: the audit trail, certificate issues, each revision as sealed;
- `readonly`: the archive opened read-only (`open_readonly`).

Which calibration is current, valid or a unit's latest is one rule (storage.current).

Every untrusted input (serial, run id, parameter name, date) is a bound parameter of a
SQLAlchemy statement, never part of a SQL string (`_common`). The public functions are
importable from here: ``from storage import queries; queries.history(...)``; each is
imported with its module when first used (`calib history` loads neither the run
questions nor the fleet's).
"""

import sys
import types

from calib_core.lazy import lazy_exports

_API = {
    "storage.queries._common": [
        "VERDICTS",
        "as_instant",
        "check_parameter",
        "check_serial",
        "check_text",
        "check_verdict",
    ],
    "storage.queries.audit": [
        "AUDIT_COLUMNS",
        "archived_revisions",
        "audit_trail",
        "certificate_issues",
    ],
    "storage.queries.equipment": [
        "LAPSED_COLUMNS",
        "due_state",
        "equipment_item",
        "equipment_list",
        "lapsed_page",
        "lapsed_runs",
        "today_utc",
    ],
    "storage.queries.fleets": [
        "FAILING_MAX",
        "FleetUnits",
        "fleet_latest_valid",
        "fleet_lineage",
        "fleet_units",
        "fleet_values",
        "models",
    ],
    "storage.queries.history": [
        "FLEET_COLUMNS",
        "FLEET_HISTORY_COLUMNS",
        "HISTORY_COLUMNS",
        "LATEST_COLUMNS",
        "UNIT_COLUMNS",
        "fleet",
        "fleet_histories",
        "fleet_history",
        "latest_calibration",
        "latest_run",
        "latest_valid",
        "parameter_history",
        "serial_parameter_history",
        "units",
    ],
    "storage.queries.unit_history": ["REVISION_COLUMNS", "history", "history_rows"],
    "storage.queries.impact": ["equipment_runs", "run_references"],
    "storage.queries.readonly": ["open_readonly"],
    "storage.queries.runs": [
        "calibration_revision",
        "current_judgements",
        "device_description",
        "earlier_descriptions",
        "export_calibration",
        "full_run_id",
        "judgement",
        "lineage",
        "repeatability_candidates",
        "run_samples",
        "run_summary",
    ],
    "storage.queries.runs_list": [
        "MAX_PAGE",
        "PER_PAGE",
        "SORTS",
        "RunFilter",
        "RunsPage",
        "choices",
        "facts",
        "run_filter",
        "runs_page",
    ],
    "storage.queries.selection": [
        "SELECTION_KEYS",
        "revised_for",
        "revision_pairs",
        "select_runs",
    ],
    "storage.queries.thermal": ["campaign_calibrations", "latest_thermal_model", "thermal_models"],
    "storage.queries.unit": ["device", "revisions", "thermal_model", "unit_parameters"],
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _API)


class _Questions(types.ModuleType):
    """This package: a question keeps its name when a module of the same name is
    imported (the import system names a submodule on its package: `history`)."""

    def __setattr__(self, name: str, value: object) -> None:
        if isinstance(value, types.ModuleType) and name in __all__:
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Questions
