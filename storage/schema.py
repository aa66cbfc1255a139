"""Archive tables: one SQLAlchemy 2 schema for SQLite and PostgreSQL.

The archive is append-only. A run is the raw bytes of one lab session
(identified by `raw_hash`, the SHA-256 over its sorted raw-file hashes); each
processing of a run is a calibration *revision*. Re-processing with other
settings or another software version adds a revision and sets `superseded_by`
on the previous one; that column is the only value ever updated in place.

Constraint names follow `NAMING` so that Alembic migrations (and SQLite batch
mode, which rebuilds tables) can address them by name on both back ends.
See docs/archive.md for the table-by-table description.
"""

from __future__ import annotations

from datetime import UTC, date, datetime
from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    CheckConstraint,
    Date,
    Float,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    String,
    Text,
    UniqueConstraint,
    text,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

from storage.instants import UTCDateTime

NAMING = {
    "ix": "ix_%(table_name)s_%(column_0_N_name)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}

SHA256_LEN = 64
NAME_LEN = 64  # serials, run ids: see storage.naming.check_safe_name


def utcnow() -> datetime:
    return datetime.now(UTC)


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING)
    type_annotation_map = {dict[str, Any]: JSON, datetime: UTCDateTime, date: Date}


class Device(Base):
    """One IMU unit: its serial, and the description it was first archived under.

    The description (model, manufacturer, specification) is the unit's *registered*
    one, never updated; what each run said is kept with the run (``runs.model``...,
    migration 0006), and a run that names another model or manufacturer fails its
    ``device:description`` check.
    """

    __tablename__ = "devices"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    serial: Mapped[str] = mapped_column(String(NAME_LEN), unique=True)
    model: Mapped[str] = mapped_column(String(200), index=True)  # fleet and unit queries
    manufacturer: Mapped[str] = mapped_column(String(200))
    specification: Mapped[str | None] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Equipment(Base):
    """A rate table, centrifuge, chamber, DAQ... identified by (kind, serial)."""

    __tablename__ = "equipment"
    __table_args__ = (UniqueConstraint("kind", "serial"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    kind: Mapped[str] = mapped_column(String(100))
    model: Mapped[str | None] = mapped_column(String(200))
    serial: Mapped[str] = mapped_column(String(200))
    accuracy_class: Mapped[str | None] = mapped_column(String(100))
    # As first seen; the value valid for a given run is the snapshot in run_equipment.
    calibration_due: Mapped[date | None]
    calibrated_on: Mapped[date | None]


class Run(Base):
    """One lab session of one unit: its raw bytes and the circumstances."""

    __tablename__ = "runs"
    # A unit's runs in time order, the later archived last among equal starts: latest-valid
    # and history queries (migrations 0003, 0005).
    __table_args__ = (Index("ix_runs_device_id_started_at_id", "device_id", "started_at", "id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[str] = mapped_column(String(NAME_LEN), unique=True)
    device_id: Mapped[int] = mapped_column(ForeignKey("devices.id"), index=True)
    started_at: Mapped[datetime] = mapped_column(index=True)
    operator: Mapped[str | None] = mapped_column(String(200))
    procedure: Mapped[str] = mapped_column(String(100))
    site: Mapped[dict[str, Any]]
    gravity: Mapped[float] = mapped_column(Float)  # m/s^2 used by the solver
    environment: Mapped[dict[str, Any]]
    manifest_text: Mapped[str | None] = mapped_column(Text)
    raw_hash: Mapped[str] = mapped_column(String(SHA256_LEN), unique=True)
    # The unit as this run's manifest describes it (migration 0006; runs archived
    # before got their device row's description).
    model: Mapped[str] = mapped_column(String(200))
    manufacturer: Mapped[str] = mapped_column(String(200))
    specification: Mapped[str | None] = mapped_column(Text)
    tolerance_profile: Mapped[str | None] = mapped_column(String(200))
    run_dir: Mapped[str] = mapped_column(String(500))  # relative to the file store root
    samples_path: Mapped[str | None] = mapped_column(String(500))  # relative, Parquet
    samples_sha256: Mapped[str | None] = mapped_column(String(SHA256_LEN))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class RunEquipment(Base):
    """Equipment used in a run, with its calibration validity as it was then."""

    __tablename__ = "run_equipment"
    __table_args__ = (
        UniqueConstraint("run_id", "equipment_id"),
        # The latest due date recorded for each piece of equipment (migration 0005).
        Index("ix_run_equipment_equipment_id_calibration_due", "equipment_id", "calibration_due"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id"), index=True)
    equipment_id: Mapped[int] = mapped_column(ForeignKey("equipment.id"), index=True)
    calibration_due: Mapped[date | None]
    calibrated_on: Mapped[date | None]


class RawFileRow(Base):
    """One raw input file; the bytes live in the content-addressed store."""

    __tablename__ = "raw_files"
    __table_args__ = (UniqueConstraint("run_id", "name"), CheckConstraint("size >= 0", "size"))

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id"))
    name: Mapped[str] = mapped_column(String(500))  # original file name
    sha256: Mapped[str] = mapped_column(String(SHA256_LEN), index=True)
    size: Mapped[int] = mapped_column(BigInteger)  # bytes
    format: Mapped[str] = mapped_column(String(50))
    stored_path: Mapped[str] = mapped_column(String(500))  # relative to the file store root


class CalibrationRow(Base):
    """One revision of the processing of a run."""

    __tablename__ = "calibrations"
    __table_args__ = (
        UniqueConstraint("run_id", "revision"),
        UniqueConstraint("run_id", "settings_hash", "software_version"),
        CheckConstraint("revision >= 1", "revision"),
        # A run's current revision and its verdict from the index alone (migration 0005).
        Index(
            "ix_calibrations_current",
            "run_id",
            "verdict",
            "profile_name",
            sqlite_where=text("superseded_by IS NULL"),
            postgresql_where=text("superseded_by IS NULL"),
            postgresql_include=["id"],
        ),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id"))
    revision: Mapped[int] = mapped_column(Integer)
    settings_hash: Mapped[str] = mapped_column(String(SHA256_LEN))
    settings: Mapped[dict[str, Any]]
    software_version: Mapped[str] = mapped_column(String(100))
    source_revision: Mapped[str | None] = mapped_column(String(100))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    superseded_by: Mapped[int | None] = mapped_column(ForeignKey("calibrations.id"))
    document: Mapped[dict[str, Any]]  # Calibration.to_dict()
    verdict: Mapped[str] = mapped_column(String(20))
    profile_name: Mapped[str | None] = mapped_column(String(200))
    profile_version: Mapped[str | None] = mapped_column(String(100))


class ProcessingStep(Base):
    """A pipeline step's StepRecord, in order, for one calibration revision."""

    __tablename__ = "processing_steps"
    __table_args__ = (UniqueConstraint("calibration_id", "seq"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id"), index=True)
    calibration_id: Mapped[int] = mapped_column(ForeignKey("calibrations.id"))
    seq: Mapped[int] = mapped_column(Integer)
    name: Mapped[str] = mapped_column(String(200))
    settings: Mapped[dict[str, Any]]
    statistics: Mapped[dict[str, Any]]
    software_version: Mapped[str] = mapped_column(String(100))
    source_revision: Mapped[str | None] = mapped_column(String(100))


class ParameterRow(Base):
    """One estimated parameter (long table, for trend and fleet queries)."""

    __tablename__ = "parameters"
    __table_args__ = (
        CheckConstraint("std IS NULL OR std >= 0", "std_nonnegative"),
        # One parameter of one calibration (history, lineage); also serves lookups
        # by calibration alone, so 0003 replaced the single-column index with it.
        Index("ix_parameters_calibration_id_name", "calibration_id", "name"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    calibration_id: Mapped[int] = mapped_column(ForeignKey("calibrations.id"))
    name: Mapped[str] = mapped_column(String(100), index=True)  # canonical, calib_core.params
    value: Mapped[float] = mapped_column(Float)  # SI
    std: Mapped[float | None] = mapped_column(Float)  # standard uncertainty, SI
    unit: Mapped[str] = mapped_column(String(50))
    temperature_c: Mapped[float | None] = mapped_column(Float)


class CheckResultRow(Base):
    """One check of a calibration against a limit of a tolerance profile."""

    __tablename__ = "check_results"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    calibration_id: Mapped[int] = mapped_column(ForeignKey("calibrations.id"), index=True)
    name: Mapped[str] = mapped_column(String(200))
    value: Mapped[float | None] = mapped_column(Float)
    limit: Mapped[float | None] = mapped_column(Float)
    passed: Mapped[bool] = mapped_column(Boolean)
    detail: Mapped[str] = mapped_column(Text, default="")
    profile_name: Mapped[str | None] = mapped_column(String(200))
    profile_version: Mapped[str | None] = mapped_column(String(100))


class ThermalModelRow(Base):
    """A temperature-compensation model of one device (calib_core.thermal.ThermalModel).

    Fitted from several calibrations (a thermal campaign); a refit adds a row
    and sets `superseded_by` on the previous one, as for calibrations.
    """

    __tablename__ = "thermal_models"
    __table_args__ = (CheckConstraint("t_max > t_min", "t_range"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    device_id: Mapped[int] = mapped_column(ForeignKey("devices.id"), index=True)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    model_name: Mapped[str] = mapped_column(String(100))
    model_version: Mapped[str] = mapped_column(String(100))
    t_ref: Mapped[float] = mapped_column(Float)  # deg C
    t_min: Mapped[float] = mapped_column(Float)  # deg C
    t_max: Mapped[float] = mapped_column(Float)  # deg C
    document: Mapped[dict[str, Any]]  # ThermalModel.to_dict()
    calibration_ids: Mapped[list[int]] = mapped_column(JSON)
    superseded_by: Mapped[int | None] = mapped_column(ForeignKey("thermal_models.id"))


class ValidationRow(Base):
    """A run's calibration revision compared with independent implementations
    (`calib validate`, storage.validation): the comparison document as printed, sealed
    by the digest its "validated" audit event carries. Never updated or deleted."""

    __tablename__ = "validations"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    calibration_id: Mapped[int] = mapped_column(ForeignKey("calibrations.id"), index=True)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    software_version: Mapped[str] = mapped_column(String(100))
    document: Mapped[dict[str, Any]]  # pipelines.validation.compare.validate_run
    digest: Mapped[str] = mapped_column(String(SHA256_LEN))


class Seal(Base):
    """The sealed record of one calibration revision (storage.seal).

    ``record`` is the canonical content of the revision's rows and files as
    archived; ``digest`` its SHA-256, also carried by the revision's event in
    the audit chain. ``texts`` (record format 2, migration 0008): the stored text
    of each JSON column the record holds by its hash, outside the digest, to show
    a change field by field; a column of its own so that reading ``record``'s
    ``files`` does not parse them. Never updated or deleted.
    """

    __tablename__ = "seals"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    calibration_id: Mapped[int] = mapped_column(ForeignKey("calibrations.id"), unique=True)
    digest: Mapped[str] = mapped_column(String(SHA256_LEN))
    record: Mapped[dict[str, Any]]
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    texts: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)


class AuditEvent(Base):
    """One event of the append-only audit chain (storage.seal): who, when, what, why.

    ``hash`` is the SHA-256 over the other fields, ``prev_hash`` that of the event
    ``seq - 1`` (zeros for the first), so the events form one chain. ``actor`` is who
    the writer says it is; ``db_user`` (migration 0009) who wrote it as the database
    knows it: PostgreSQL's ``session_user``, the OS user on SQLite (NULL before 0009).
    """

    __tablename__ = "audit_events"

    seq: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    at: Mapped[datetime] = mapped_column(index=True)
    actor: Mapped[str] = mapped_column(String(200))
    action: Mapped[str] = mapped_column(String(50))
    run_id: Mapped[str | None] = mapped_column(String(NAME_LEN), index=True)
    revision: Mapped[int | None] = mapped_column(Integer)
    reason: Mapped[str | None] = mapped_column(Text)
    detail: Mapped[dict[str, Any]]
    digest: Mapped[str | None] = mapped_column(String(SHA256_LEN))
    prev_hash: Mapped[str] = mapped_column(String(SHA256_LEN), unique=True)
    hash: Mapped[str] = mapped_column(String(SHA256_LEN), unique=True)
    db_user: Mapped[str | None] = mapped_column(String(200), nullable=True)


class UnitLatest(Base):
    """Each unit's latest run and latest valid calibration (storage.unit_latest).

    Derived from runs and calibrations, never entered: rewritten for the unit in the
    transaction that archives or revises one of its runs, built for every unit by
    migration 0007, and compared with its recomputation by `calib verify`. It saves
    the fleet page a walk of each unit's runs (thousands of units per request). The
    ids have no foreign keys: a derived row must not stand in the way of what it is
    derived from (verify reports it when they disagree).

    run_id : the unit's latest run (by start, the later archived among equal starts).
    calibration_id, verdict, profile_name : that run's current revision, its verdict
        and tolerance profile (None if it has none).
    valid_calibration_id : the current revision with verdict "pass" of the unit's
        latest run that has one (None if none has).
    """

    __tablename__ = "unit_latest"

    device_id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    run_id: Mapped[int] = mapped_column(Integer)
    calibration_id: Mapped[int | None] = mapped_column(Integer)
    verdict: Mapped[str | None] = mapped_column(String(20))
    profile_name: Mapped[str | None] = mapped_column(String(200))
    valid_calibration_id: Mapped[int | None] = mapped_column(Integer)


class UnitLatestValue(Base):
    """Each parameter of each unit's latest valid calibration (storage.unit_latest), one
    value per name: of temperature-dependent values the one nearest 20 deg C.

    Derived like unit_latest (rewritten with a unit's row, checked by `calib verify`);
    keyed by model, name and serial, so a fleet's values for one parameter are one
    range of the key, in serial order (SQLite: a table without row ids).
    """

    __tablename__ = "unit_latest_values"
    __table_args__ = {"sqlite_with_rowid": False}

    model: Mapped[str] = mapped_column(String(200), primary_key=True)
    name: Mapped[str] = mapped_column(String(100), primary_key=True)
    serial: Mapped[str] = mapped_column(String(NAME_LEN), primary_key=True)
    device_id: Mapped[int] = mapped_column(Integer, index=True)
    calibration_id: Mapped[int] = mapped_column(Integer)
    value: Mapped[float] = mapped_column(Float)
    temperature_c: Mapped[float | None] = mapped_column(Float)


TABLES = [t.name for t in Base.metadata.sorted_tables]
