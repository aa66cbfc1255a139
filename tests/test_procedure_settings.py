"""Every procedure's typed settings: the whole [run.settings] is checked, nothing ignored.

Per procedure an unknown (misspelt) key is refused naming the key and the closest valid one,
a value of the wrong type and a value out of bounds naming the key, the value and what is
allowed; the same through the solver, the manifest (naming its file) and `calib process`.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from calib_core import procedures
from calib_core.procedures import ALL, BY_NAME, SettingError, solve
from calib_core.simulate import random_errors, six_position_integral_run
from calib_testing.run_writers import dumps_toml, six_position_manifest, write_csv_run
from pipelines.ingest import IngestError, discover_runs
from pipelines.ingest.manifest import parse_manifest
from pipelines.process import process_run
from storage.db import resolve_archive

# procedure: (misspelt key, the key it means), (key, value of a wrong type),
# (key, value out of bounds)
CASES = {
    "six_position": (("accel_solvr", "accel_solver"), ("accel_solver", 1),
                     ("gyro_range_dps", -250.0)),
    "six_position_integral": (("accel_solvr", "accel_solver"), ("turns", "two"), ("turns", 0)),
    "integral": (("turn", "turns"), ("turns", 1.5), ("gyro_range_dps", 0.0)),
    "multi_position": (("modle", "model"), ("gyro_gsens", "yes"), ("gyro_range_dps", -1.0)),
    "equipment_free": (("min_interval", "min_intervals"), ("k", "6"), ("k", 0.0)),
    "sensor_array": (("mount", "mounts"), ("mounts", 3), ("turns", 0)),
    "rate_table": (("settle", "settle_s"), ("settle_s", "20"), ("settle_s", -1.0)),
    "static_bias": (("up_axes", "up_axis"), ("remove_earth_rate", "yes"),
                    ("latitude_deg", 91.0)),
    "centrifuge": (("alpah", "alpha"), ("iterations", 2.5), ("alpha", 1.5)),
}  # fmt: skip


def test_every_procedure_has_its_cases():
    assert set(CASES) == set(BY_NAME) == set(procedures.PROCEDURES)


@pytest.mark.parametrize("name", list(CASES))
def test_unknown_key_is_refused_with_the_closest_valid_one(name):
    (typo, meant), _, _ = CASES[name]
    with pytest.raises(SettingError) as err:
        procedures.validate_settings(name, {typo: 1})
    assert str(err.value) == (
        f"run.settings.{typo}: unknown setting of {name}; did you mean {meant}?"
    )


@pytest.mark.parametrize("name", list(CASES))
def test_wrong_type_is_refused_naming_key_value_and_allowed(name):
    _, (key, value), _ = CASES[name]
    with pytest.raises(SettingError) as err:
        procedures.validate_settings(name, {key: value})
    allowed = BY_NAME[name].all_settings().items[key].allowed()
    assert err.value.key == key
    assert repr(value) in str(err.value) and allowed in str(err.value)


@pytest.mark.parametrize("name", list(CASES))
def test_out_of_bounds_is_refused_naming_key_value_and_range(name):
    _, _, (key, value) = CASES[name]
    with pytest.raises(SettingError) as err:
        procedures.validate_settings(name, {key: value})
    assert err.value.key == key and repr(value) in str(err.value)
    assert re.search(r"positive|in [\[(]|>=|non-negative", str(err.value)), str(err.value)


@pytest.mark.parametrize("name", list(CASES))
def test_defaults_and_tables_pass(name):
    proc = BY_NAME[name]
    given = {s.name: s.default for s in proc.all_settings() if s.default is not None}
    typed = proc.validate({**given, "outliers": {"n_sigma": 4.0}})
    assert isinstance(typed, proc.settings.type)  # what its solver takes
    assert typed.as_dict() == proc.settings.defaults() | {
        k: v for k, v in given.items() if k in proc.settings
    }
    with pytest.raises(
        SettingError,
        match=r"run.settings.outliers.sigmaa: unknown setting of "
        r"\[run.settings.outliers\]; did you mean n_sigma\?",
    ):
        proc.validate({"outliers": {"sigmaa": 4.0}})
    with pytest.raises(SettingError, match="run.settings.lowpass: expected a table"):
        proc.validate({"lowpass": 5.0})


def test_the_solver_refuses_a_misspelt_setting_instead_of_ignoring_it():
    rng = np.random.default_rng(3)
    run = six_position_integral_run(random_errors(rng), rng)
    with pytest.raises(
        ValueError,
        match="accel_solvr: unknown setting of six_position_integral; did you mean accel_solver",
    ):
        solve("six_position_integral", run.segments, run.gravity, {"accel_solvr": "kalman"})


def test_a_setting_of_another_procedure_names_whose_it_is():
    """A static-bias key in a six-position run (or a run given the wrong procedure) is
    refused, and the refusal says which procedure declares it."""
    with pytest.raises(SettingError) as err:
        procedures.validate_settings("six_position_integral", {"up_axis": "-z"})
    assert str(err.value).startswith(
        "run.settings.up_axis: unknown setting of six_position_integral; expected one of "
    )
    assert str(err.value).endswith("; up_axis is a setting of static_bias")
    with pytest.raises(
        SettingError,
        match=r"turns is a setting of six_position_integral, integral and sensor_array$",
    ):
        solve("rate_table", {}, 9.81, {"turns": 2})


def _manifest_text(procedure: str, settings: dict) -> str:
    doc = six_position_manifest("SET-1")
    doc["run"] = {**doc["run"], "procedure": procedure, "settings": settings}
    doc["segments"] = [{"label": "x_up", "file": "imu.csv"}]
    doc["format"] = {"kind": "csv"}
    return dumps_toml(doc)


def test_the_manifest_names_its_file_and_the_key():
    with pytest.raises(IngestError) as err:
        parse_manifest(_manifest_text("static_bias", {"up_axes": "-z"}), "lab/run.toml")
    assert str(err.value).startswith("lab/run.toml")
    assert "run.settings.up_axes" in str(err.value) and "did you mean up_axis?" in str(err.value)
    with pytest.raises(
        IngestError,
        match=r"run.settings.n_sigma.*expected a positive number, "
        r"got -3",
    ):
        parse_manifest(_manifest_text("static_bias", {"n_sigma": -3}), "run.toml")


def test_the_manifest_names_the_line_of_the_key():
    for settings, key, line in (
        ({"turns": 0}, "run.settings.turns", "turns = 0"),
        ({"outliers": {"n_sigm": 4}}, "run.settings.outliers.n_sigm", "n_sigm = 4"),
    ):
        text = _manifest_text("six_position_integral", settings)
        lines = text.splitlines()
        with pytest.raises(IngestError) as err:
            parse_manifest(text, "run.toml")
        number = err.value.line
        assert number is not None and lines[number - 1].strip() == line, (text, number)
        assert str(err.value).startswith(f"run.toml line {number}: field '{key}': ")


def test_process_refuses_the_run_cleanly(tmp_path: Path):
    rng = np.random.default_rng(4)
    sim = six_position_integral_run(random_errors(rng), rng)
    doc = six_position_manifest("SET-2")
    doc["run"] = {**doc["run"], "settings": {"accel_solvr": "kalman"}}
    folder = write_csv_run(sim.segments, tmp_path / "run", doc).parent
    arch = resolve_archive(str(tmp_path / "archive"))
    arch.upgrade()
    outcome = process_run(discover_runs([folder])[0], arch)
    assert outcome["status"] == "failed"
    assert "run.toml" in outcome["error"] and "did you mean accel_solver?" in outcome["error"]


def test_every_declaration_is_complete():
    for proc in ALL:
        assert proc.summary and proc.segments and proc.reference and proc.conditions
        for s in proc.all_settings():
            assert s.meaning and s.allowed(), (proc.name, s.name)
            s.check(s.default)  # a default is allowed by its own setting


def test_docs_procedures_md_is_generated_from_the_objects():
    from pipelines.commands.procedures import generated_section, markdown

    doc = (Path(__file__).resolve().parents[1] / "docs" / "procedures.md").read_text()
    assert generated_section(doc) == markdown(), (
        "docs/procedures.md is stale: run python -m pipelines.commands.procedures "
        "docs/procedures.md"
    )


def test_calib_procedures_prints_the_same():
    from typer.testing import CliRunner

    from pipelines.cli import app
    from pipelines.commands.procedures import procedure_markdown

    done = CliRunner().invoke(app, ["procedures", "static_bias"])
    assert done.exit_code == 0, done.output
    assert done.stdout.strip() == procedure_markdown(BY_NAME["static_bias"]).strip()
    assert "| `up_axis` | text |" in done.stdout and "static_temperature_spread_c" in done.stdout
    done = CliRunner().invoke(app, ["procedures", "static_bais"])
    assert done.exit_code != 0 and "unknown procedure 'static_bais'" in done.output


def test_the_tables_are_the_steps_own_keys():
    from calib_core.preprocess import chain
    from pipelines.uncertainty import SETTINGS as UNCERTAINTY_KEYS

    # The preprocessing tables are the chain's own declarations; the budget reads every key.
    assert {k: procedures.TABLES[k] for k in chain.PREPROCESSING} == chain.PREPROCESSING
    assert set(procedures.TABLES["uncertainty"].items) == set(UNCERTAINTY_KEYS)
    with pytest.raises(
        SettingError,
        match=r"run.settings.outliers.n_sigma: expected a "
        r"positive number, got -1",
    ):
        procedures.validate_settings("six_position", {"outliers": {"n_sigma": -1}})
    with pytest.raises(
        SettingError,
        match=r"run.settings.lowpass.apply_to must be one of "
        r"'static', 'all', got 'some'",
    ):
        procedures.validate_settings("rate_table", {"lowpass": {"apply_to": "some"}})


def test_the_declared_defaults_are_the_solvers():
    """Where a solver keeps its own defaults (called without the procedure object), they
    are the declared ones: docs/procedures.md and `calib procedures` print what is used."""
    import dataclasses
    import inspect

    from calib_core.solvers import equipment_free, multi_position
    from calib_core.solvers.centrifuge_model import CentrifugeSettings
    from calib_core.solvers.rate_table import rate_point

    # multi_position and equipment_free: the solver's declaration is the procedure's.
    assert BY_NAME["multi_position"].settings is multi_position.SETTINGS
    assert BY_NAME["equipment_free"].settings is equipment_free.SETTINGS
    fields = {f.name: f.default for f in dataclasses.fields(CentrifugeSettings)}
    declared = BY_NAME["centrifuge"].settings.defaults()
    shared = {k for k in declared if fields.get(k, dataclasses.MISSING) is not dataclasses.MISSING}
    assert shared >= {"alpha", "t_test", "steer", "iterations", "zero_shift_limit"}
    assert {k: declared[k] for k in shared} == {k: fields[k] for k in shared}
    signature = inspect.signature(rate_point).parameters
    for key in ("settle_s", "record_s"):
        assert BY_NAME["rate_table"].settings.defaults()[key] == signature[key].default


@pytest.mark.parametrize("name", list(CASES))
def test_solvers_take_their_typed_settings(name):
    """`solve` checks the run's settings once and hands the procedure's solver its typed
    values (defaults filled, the shared tables left out); a solver called directly parses
    a mapping at its door, refusing a bad value by the same rule."""
    from calib_core.calibration import Calibration

    proc = BY_NAME[name]
    own = next(s for s in proc.settings if s.default is not None)
    given = {own.name: own.default, "outliers": {"n_sigma": 4.0}}
    seen = []

    def spy(segments, gravity, settings):
        seen.append(settings)
        return Calibration(procedure=name, gravity=gravity)

    solve(name, {}, 9.81, given, solver=spy)
    (typed,) = seen
    assert type(typed) is proc.settings.type and proc.settings.parse(typed) is typed
    assert typed.as_dict() == proc.settings.defaults()
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(typed, own.name, own.default)
    _, (key, value), _ = CASES[name]
    if key in proc.settings:  # not a shared setting: the solver's own door refuses it
        with pytest.raises(SettingError, match=rf"run\.settings\.{key}: expected"):
            proc.solver({}, 9.81, {key: value})
