"""The sealed record of a calibration revision: what a seal hashes.

A revision's *record* is read back from its rows (run with the unit as it
describes it, device, equipment links, raw files, calibration with its document,
steps, parameters, checks) together with the SHA-256 of every file the revision
wrote (protocol...), serialised as canonical JSON, and hashed (the *digest*);
storage.seal keeps it and chains the digest, storage.seal_check compares it with
the rows as they are now.

Record formats. Format 1 (the records of before, no ``format`` key) holds every
value as decoded from its row. Format 2 (``"format": 2``, written since) holds a
JSON column (the calibration document and settings, a step's settings and
statistics, a run's site and environment) as the SHA-256 of the text the database
stores (``"sha256:<hex>"``), and the seal keeps that text beside the record
(``seals.texts``, outside the digest) to show a change field by field. So verify
neither decodes nor re-encodes the large JSON values, which would cost more than
the rest of the verify. A migration that
rewrote a JSON column's text, even to equal JSON, would break format 2 seals:
that text is what they hold. Both formats verify; `records` builds either.
"""

from __future__ import annotations

import hashlib
import json
from collections import defaultdict
from collections.abc import Iterator
from datetime import date, datetime
from functools import cache
from typing import Any

from sqlalchemy import JSON, Connection, Select, Text, bindparam, cast, select

from storage import schema

CHUNK = 500  # calibrations per round of record queries
FORMAT = 2  # record format of new seals (module docstring); 1: before it had a number
FORMATS = (1, 2)  # the record formats this version reads
TEXTS = "texts"  # a record's JSON texts (format 2): outside the digest, in seals.texts


def canonical(value: Any) -> bytes:
    """Canonical JSON (sorted keys, no spaces, ISO dates) as UTF-8: what is hashed.

    Records are trees read from the database, never cyclic: the encoder's cycle
    check (a quarter of its time on a record) is off.
    """
    return json.dumps(
        value,
        sort_keys=True,
        separators=(",", ":"),
        ensure_ascii=False,
        default=_iso,
        check_circular=False,
    ).encode()


def _iso(value: Any) -> str:
    if isinstance(value, date | datetime):
        return value.isoformat()
    raise TypeError(f"{type(value).__name__} is not part of a record")


def sha256_hex(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


_RUN = ("run_id", "started_at", "operator", "procedure", "site", "gravity", "environment",
        "manifest_text", "raw_hash", "tolerance_profile", "run_dir", "samples_path",
        "samples_sha256", "created_at")  # fmt: skip
_CAL = (
    "revision",
    "settings_hash",
    "settings",
    "software_version",
    "source_revision",
    "created_at",
    "document",
    "verdict",
    "profile_name",
    "profile_version",
)
_DEVICE = ("serial", "model", "manufacturer", "specification")
_DESCRIPTION = ("model", "manufacturer", "specification")  # of the unit, kept per run
_RAW = ("name", "sha256", "size", "format", "stored_path")
_STEP = ("seq", "name", "settings", "statistics", "software_version", "source_revision")
_PARAM = ("name", "value", "std", "unit", "temperature_c")
_CHECK = ("name", "value", "limit", "passed", "detail", "profile_name", "profile_version")


class _Stored(str):
    """The text a JSON column holds, read so at format 2 (`_hash_stored` replaces it)."""


def _cols(model: type, names: tuple[str, ...], prefix: str = "", form: int = 1) -> list:
    """Columns `names` of `model` labelled ``prefix + name``; from format 2 on, a JSON
    column is read as the text it is stored as."""
    stored = _stored_names(model, names, form)
    return [_as_read(getattr(model, n), n in stored).label(prefix + n) for n in names]


def _as_read(col: Any, stored: bool) -> Any:
    return cast(col, Text) if stored else col


@cache
def _stored_names(model: type, names: tuple[str, ...], form: int) -> frozenset[str]:
    """The JSON columns among `names`: read as stored text from format 2 on."""
    if form < 2:
        return frozenset()
    return frozenset(n for n in names if isinstance(getattr(model, n).type, JSON))


def _fields(m: Any, names: tuple[str, ...], prefix: str, stored: frozenset[str]) -> dict:
    """{name: value} of one result row; a stored JSON text is marked `_Stored`."""
    return {n: _leaf(m[prefix + n], n in stored) for n in names}


def _leaf(value: Any, stored: bool) -> Any:
    return _Stored(value) if stored and value is not None else value


def records(
    conn: Connection,
    cal_ids: list[int],
    files: dict[int, dict[str, str]] | None = None,
    *,
    form: int = FORMAT,
) -> dict[int, dict[str, Any]]:
    """The record of each calibration revision, as its rows are now.

    Parameters
    ----------
    conn : an open connection (inside the archiving transaction, or verify's).
    cal_ids : calibration ids (a few hundred at a time: they go into IN lists).
    files : calibration id -> {path relative to the file store: sha256} of the files
        the revision wrote; missing ids get ``{}``.
    form : record format (module docstring): 1 every value decoded, 2 JSON columns
        as the SHA-256 of their stored text, which goes under ``texts``.

    Returns
    -------
    calibration id -> record: one key per table (``runs``, ``devices``,
    ``run_equipment``, ``raw_files``, ``calibrations``, ``processing_steps``,
    ``parameters``, ``check_results``) plus ``files`` (and, format 2, ``format``
    and ``texts``: the stored texts, nested as the record). Rows of a table are keyed
    by a label (parameter name, step ``seq:name``...) so a difference names the row.

    ``devices`` is the unit's row (serial and registered description); the run's
    own description (``runs.model``, ``manufacturer``, ``specification``, migration
    0006) is in ``runs`` field by field where it differs from the registered one.
    So both are sealed, and a record sealed when they agreed (every record sealed
    before 0006, which copied the device row's description into the runs) keeps its
    digest; a run's field changed to differ shows as sealed "(absent)".
    """
    head = conn.execute(_head_query(form), {"ids": cal_ids}).mappings()
    run_stored = _stored_names(schema.Run, _RUN, form)
    cal_stored = _stored_names(schema.CalibrationRow, _CAL, form)
    out: dict[int, dict[str, Any]] = {}
    run_of: dict[int, int] = {}
    for m in head:
        run_of[m["cal_pk"]] = m["run_pk"]
        out[m["cal_pk"]] = {
            "runs": _fields(m, _RUN, "r_", run_stored) | _own_description(m),
            "calibrations": _fields(m, _CAL, "c_", cal_stored),
            "devices": {n: m["d_" + n] for n in _DEVICE},
            "files": dict(sorted((files or {}).get(m["cal_pk"], {}).items())),
        }
    by_run = _run_children(conn, sorted(set(run_of.values())))
    by_cal = _calibration_children(conn, list(out), form)
    for cal_pk, rec in out.items():
        rec.update(by_run[run_of[cal_pk]])
        rec.update(by_cal[cal_pk])
        if form >= 2:
            rec["format"] = form
            rec[TEXTS] = _hash_stored(rec)
    return out


# The queries of `records` are built once per process (they depend on the schema and the
# format only; their IN lists are expanding parameters ``ids``). Building them, the chain
# head and the two inserts for every revision was about half of the cost of sealing one.
_IDS = bindparam("ids", expanding=True)


@cache
def _head_query(form: int) -> Select:
    """Each revision's run, calibration and device fields, for calibration ids ``ids``."""
    return (
        select(
            schema.CalibrationRow.id.label("cal_pk"),
            schema.Run.id.label("run_pk"),
            *_cols(schema.Run, _RUN, "r_", form),
            *_cols(schema.CalibrationRow, _CAL, "c_", form),
            *_cols(schema.Device, _DEVICE, "d_"),
            *_cols(schema.Run, _DESCRIPTION, "u_"),
        )
        .join(schema.Run, schema.Run.id == schema.CalibrationRow.run_id)
        .join(schema.Device, schema.Device.id == schema.Run.device_id)
        .where(schema.CalibrationRow.id.in_(_IDS))
    )


def _hash_stored(record: dict[str, Any]) -> dict[str, Any]:
    """Replace every stored JSON text of `record` by ``"sha256:<hex>"``, in place; return
    the texts, nested as the record is (``{table: {field: text}}`` or
    ``{table: {row: {field: text}}}``)."""
    texts: dict[str, Any] = {}
    for table in _JSON_TABLES:
        rows = record[table]
        found: dict[str, Any] = _hash_fields(rows)  # runs, calibrations: their fields
        for label, row in rows.items():
            if isinstance(row, dict) and (in_row := _hash_fields(row)):  # a child table's row
                found[label] = in_row
        if found:
            texts[table] = found
    return texts


def _hash_fields(fields: dict[str, Any]) -> dict[str, str]:
    """Hash the stored texts among `fields` in place; return them by field name."""
    texts = {}
    for name, leaf in fields.items():
        if isinstance(leaf, _Stored):
            texts[name] = str(leaf)
            fields[name] = text_digest(leaf)
    return texts


# The record's tables that have JSON columns: where `_hash_stored` looks.
_JSON_TABLES = tuple(
    table
    for table, model, names in (
        ("runs", schema.Run, _RUN),
        ("calibrations", schema.CalibrationRow, _CAL),
        ("processing_steps", schema.ProcessingStep, _STEP),
        ("parameters", schema.ParameterRow, _PARAM),
        ("check_results", schema.CheckResultRow, _CHECK),
    )
    if _stored_names(model, names, 2)
)


def text_digest(stored: str) -> str:
    """What a format 2 record holds for a JSON column's stored text."""
    return "sha256:" + sha256_hex(stored.encode())


def _own_description(m: Any) -> dict[str, Any]:
    """The fields of the run's own description that differ from its device row's."""
    return {n: m["u_" + n] for n in _DESCRIPTION if m["u_" + n] != m["d_" + n]}


def labelled(rows: list[tuple[str, dict[str, Any]]]) -> dict[str, dict[str, Any]]:
    """Rows keyed by label; a repeated label gets ``#2``, ``#3``... in row order."""
    out: dict[str, dict[str, Any]] = {}
    for label, row in rows:
        key, n = label, 1
        while key in out:
            n += 1
            key = f"{label}#{n}"
        out[key] = row
    return out


def _run_children(conn: Connection, run_pks: list[int]) -> dict[int, dict[str, Any]]:
    eq_rows: dict[int, list] = defaultdict(list)
    equipment_query, raw_query = _run_children_queries()
    for m in conn.execute(equipment_query, {"ids": run_pks}).mappings():
        row = {k: v for k, v in m.items() if k != "run_id"}
        eq_rows[m["run_id"]].append((f"{m['kind']}:{m['serial']}", row))
    raw_rows: dict[int, list] = defaultdict(list)
    for m in conn.execute(raw_query, {"ids": run_pks}).mappings():
        raw_rows[m["run_id"]].append((m["name"], {n: m[n] for n in _RAW}))
    return {
        pk: {"run_equipment": labelled(eq_rows[pk]), "raw_files": labelled(raw_rows[pk])}
        for pk in run_pks
    }


def _calibration_children(
    conn: Connection, cal_pks: list[int], form: int
) -> dict[int, dict[str, Any]]:
    out: dict[int, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for table, names, stored, query in _calibration_children_queries(form):
        # verify builds every row of the archive here: the row's dict made at once and
        # only its JSON columns marked spares a function call per value
        marked = [n for n in names if n in stored]
        for cal_pk, *values in conn.execute(query, {"ids": cal_pks}):
            row = dict(zip(names, values, strict=True))
            for n in marked:
                row[n] = _leaf(row[n], True)
            label = f"{row['seq']}:{row['name']}" if table == "processing_steps" else row["name"]
            out[cal_pk][table].append((label, row))
    return {pk: {t: labelled(out[pk][t]) for t, *_ in _CHILD_TABLES} for pk in cal_pks}


# A revision's child tables: (record key, model, sealed columns, order within a revision).
_CHILD_TABLES = (
    ("processing_steps", schema.ProcessingStep, _STEP, schema.ProcessingStep.seq),
    ("parameters", schema.ParameterRow, _PARAM, schema.ParameterRow.name),
    ("check_results", schema.CheckResultRow, _CHECK, schema.CheckResultRow.name),
)


@cache
def _calibration_children_queries(form: int) -> list[tuple[str, tuple, frozenset, Select]]:
    """(record key, columns, stored JSON columns, query) of each child table of a revision."""
    return [
        (
            table,
            names,
            _stored_names(model, names, form),
            select(model.calibration_id, *_cols(model, names, form=form))
            .where(model.calibration_id.in_(_IDS))
            .order_by(model.calibration_id, order, model.id),
        )
        for table, model, names, order in _CHILD_TABLES
    ]


@cache
def _run_children_queries() -> tuple[Select, Select]:
    """The queries of a run's equipment and raw files, for run ids ``ids``."""
    equipment = (
        select(
            schema.RunEquipment.run_id,
            schema.Equipment.kind,
            schema.Equipment.serial,
            schema.Equipment.model,
            schema.Equipment.accuracy_class,
            schema.RunEquipment.calibration_due,
            schema.RunEquipment.calibrated_on,
        )
        .join(schema.Equipment, schema.Equipment.id == schema.RunEquipment.equipment_id)
        .where(schema.RunEquipment.run_id.in_(_IDS))
        .order_by(schema.RunEquipment.run_id, schema.Equipment.kind, schema.Equipment.serial)
    )
    raw = (
        select(schema.RawFileRow.run_id, *_cols(schema.RawFileRow, _RAW))
        .where(schema.RawFileRow.run_id.in_(_IDS))
        .order_by(schema.RawFileRow.run_id, schema.RawFileRow.name)
    )
    return equipment, raw


def digest_of(record: dict[str, Any]) -> str:
    """SHA-256 of the record's canonical JSON, its stored texts (format 2) left out."""
    return sha256_hex(canonical(without_texts(record)))


def record_format(value: Any) -> int:
    """The format a sealed record's ``format`` value names (module docstring): 1 where it
    names none, 0 for a value no version of calib writes."""
    if value is None:
        return 1
    return value if type(value) is int and value >= 1 else 0


def without_texts(record: dict[str, Any]) -> dict[str, Any]:
    """The record without its stored texts (format 2): what is hashed."""
    return {k: v for k, v in record.items() if k != TEXTS}


def chunks(ids: list[int], n: int = CHUNK) -> Iterator[list[int]]:
    """`ids` in lists of at most `n` (they go into IN lists)."""
    for i in range(0, len(ids), n):
        yield ids[i : i + n]
