"""Integrity check of an archive: every archived file against its hash in the database.

`verify` re-hashes each raw object (``raw_files.stored_path`` /
``raw_files.sha256`` / ``size``) and each Parquet samples file
(``runs.samples_path`` / ``runs.samples_sha256``) and reports files that are
missing or whose bytes changed. It also checks the database's own invariants
that a crash or a manual edit could break: every run has raw files and
exactly one current calibration revision, and a revision is superseded only
by a later revision of the same run; the derived table of each unit's latest
run and latest valid calibration (storage.unit_latest) must equal its
derivation from the runs. The ``parameters`` rows of every
calibration must agree with the parameters of its stored document (both are
written from the same objects): any difference, a missing or an extra row is a
*record* problem naming run, revision, parameter, field and both values. The
settings hash of every revision is recomputed from its settings, procedure and profile
(storage.settings_hash), and for a revision judged again (storage.rejudgement.rejudge_run)
the runs its ``rejudge`` step says it was judged against. Whether a revision's numbers
are what its raw bytes give is `calib verify --recompute`'s question (pipelines.recompute).

Files the database does not reference (an archive attempt killed between
writing its files and committing its rows leaves those) are listed as
*orphans*: harmless, not problems. The file store only ever grows, so such a
file is never mistaken for archived data.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

from sqlalchemy import func, select
from sqlalchemy.engine import make_url
from sqlalchemy.orm import aliased

from storage import rawstore, unit_latest
from storage.current import CURRENT
from storage.db import Archive
from storage.schema import CalibrationRow, ParameterRow, ProcessingStep, RawFileRow, Run

ProblemKind = Literal[
    "missing",
    "mismatch",
    "outside",
    "database",
    "record",
    "chain",
    "signature",
    "untrusted",
    "checkpoint",
]


@dataclass
class Problem:
    """One integrity problem.

    Attributes
    ----------
    kind : "missing" (no file), "mismatch" (other bytes or size), "outside"
        (a stored path that leaves the file store), "database" (a broken invariant),
        "record" (parameter rows and calibration document disagree, or a row or
        file differs from its seal), "chain" (the audit chain or a seal was changed,
        a sealed event has no rows or rows no seal), "signature" (an approval
        no longer verifies), "untrusted" (an approval made with a key the lab's
        approvers file does not hold for its date), "checkpoint" (the chain does
        not extend a checkpoint written earlier: rewritten, rolled back, truncated).
    path : the file, relative to the file store root ("" for database problems;
        for record problems ``<table>/<row>/<field>``, e.g. ``parameters/acc.bias.x/value``).
    runs : run ids concerned.
    detail : what was expected and what was found.
    """

    kind: ProblemKind
    path: str
    runs: list[str]
    detail: str


@dataclass
class VerifyReport:
    """What `verify` found. ``ok`` is true when there is no problem (orphans are allowed)."""

    files_checked: int = 0
    bytes_checked: int = 0
    runs_checked: int = 0
    seals_checked: int = 0
    chain_head: tuple[int, str] = (0, "")  # (seq, hash) of the newest audit event: note it down
    # The approvers file approvals were checked against ("": not checked against one).
    approvers: str = ""
    checkpoints: list[str] = field(default_factory=list)  # the checkpoint files compared
    problems: list[Problem] = field(default_factory=list)
    orphans: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def to_dict(self) -> dict[str, Any]:
        return {"ok": self.ok, **asdict(self)}

    def add(self, kind: str, path: str, runs: list[str], detail: str) -> None:
        """Note one problem (`Problem`'s fields)."""
        self.problems.append(Problem(kind, path, runs, detail))


def _inside(root: Path, rel: str) -> Path | None:
    """root/rel if it stays inside root (a database row is not trusted to), else None."""
    p = (root / rel).resolve()
    return p if p.is_relative_to(root.resolve()) else None


def _check_file(
    report: VerifyReport, root: Path, rel: str, sha256: str, size: int | None, runs: list[str]
) -> None:
    path = _inside(root, rel)
    if path is None:
        report.add("outside", rel, runs, "path leaves the file store")
        return
    if not path.is_file():
        report.add("missing", rel, runs, f"expected sha256 {sha256}")
        return
    actual, n = rawstore.hash_and_size(path)
    report.files_checked += 1
    report.bytes_checked += n
    if actual != sha256 or (size is not None and n != size):
        report.add(
            "mismatch",
            rel,
            runs,
            f"expected sha256 {sha256}"
            + ("" if size is None else f" ({size} bytes)")
            + f", found {actual} ({n} bytes)",
        )


def sqlite_file(archive: Archive) -> Path | None:
    """The SQLite database file of the archive (None for other back ends)."""
    if not archive.is_sqlite:
        return None
    db = make_url(archive.url).database
    return Path(db).resolve() if db and db != ":memory:" else None


def verify(
    archive: Archive,
    *,
    orphans: bool = True,
    seals: bool = True,
    approvers: Any = None,
    checkpoints: list[tuple[str, dict[str, Any]]] = (),
) -> VerifyReport:
    """Re-hash every archived file, check the database invariants, the seals and the chain.

    Parameters
    ----------
    archive : the archive (schema current).
    orphans : also list files under objects/, samples/ and runs/ that no row
        references (costs a walk of the file store).
    seals : also recompute every seal, the audit chain and the approval
        signatures (storage.seal, storage.approval).
    approvers : the lab's approvers file (storage.approval.Approvers): every
        approval made with a key it does not hold for its date is a problem.
        None: approvals are not checked against one (``report.approvers`` is "").
    checkpoints : (file name, document) of checkpoints (storage.checkpoint.load):
        the chain must extend each exactly.

    Returns
    -------
    VerifyReport; ``report.ok`` is False when any file is missing or changed
    or an invariant is broken.
    """
    report = VerifyReport()
    root = archive.root
    with archive.engine().connect() as conn:
        raw_rows = conn.execute(
            select(RawFileRow.stored_path, RawFileRow.sha256, RawFileRow.size, Run.run_id)
            .join(Run, Run.id == RawFileRow.run_id)
            .order_by(RawFileRow.stored_path, Run.run_id)
        ).all()
        sample_rows = conn.execute(
            select(Run.samples_path, Run.samples_sha256, Run.run_id).where(
                Run.samples_path.is_not(None)
            )
        ).all()
        run_dirs = conn.execute(select(Run.run_dir)).scalars().all()
        report.runs_checked = len(run_dirs)
        _check_database(conn, report)
        _check_unit_latest(conn, report)
        _check_parameters(conn, report)
        _check_settings_hashes(conn, report)
        if seals:
            _check_seals(conn, root, report)
        _check_trust(conn, report, approvers, checkpoints)
    _check_store(archive, report)

    objects: dict[tuple[str, str, int], list[str]] = defaultdict(list)
    for path, sha, size, run_id in raw_rows:
        objects[(path, sha, size)].append(run_id)
    for (path, sha, size), runs in objects.items():
        _check_file(report, root, path, sha, size, runs)
    for path, sha, run_id in sample_rows:
        if sha is None:
            report.add("database", path, [run_id], "samples file has no hash")
            continue
        _check_file(report, root, path, sha, None, [run_id])

    if orphans:
        known = {p for p, _, _ in objects} | {r.samples_path for r in sample_rows}
        report.orphans = _orphans(root, known, set(run_dirs))
    return report


def _check_database(conn, report: VerifyReport) -> None:  # noqa: ANN001 - a Connection
    current = (
        select(Run.run_id, func.count(CalibrationRow.id).label("n"))
        .select_from(Run)
        .outerjoin(
            CalibrationRow,
            (CalibrationRow.run_id == Run.id) & CURRENT,
        )
        .group_by(Run.run_id)
    )
    for run_id, n in conn.execute(current.having(func.count(CalibrationRow.id) != 1)):
        report.add("database", "", [run_id], f"{n} current calibration revisions, expected 1")
    has_raw = select(RawFileRow.id).where(RawFileRow.run_id == Run.id).exists()
    no_raw = select(Run.run_id).where(~has_raw)
    for run_id in conn.execute(no_raw).scalars():
        report.add("database", "", [run_id], "run has no raw files")
    newer = aliased(CalibrationRow)
    bad_chain = (
        select(Run.run_id, CalibrationRow.revision)
        .join(CalibrationRow, CalibrationRow.run_id == Run.id)
        .join(newer, newer.id == CalibrationRow.superseded_by)
        .where(
            (newer.run_id != CalibrationRow.run_id) | (newer.revision <= CalibrationRow.revision)
        )
    )
    for run_id, rev in conn.execute(bad_chain):
        report.add(
            "database",
            "",
            [run_id],
            f"revision {rev} is superseded by a revision that is "
            "not a later revision of the same run",
        )


def _check_settings_hashes(conn, report: VerifyReport) -> None:  # noqa: ANN001 - a Connection
    """The settings hash of every revision, recomputed from its sealed rows: its settings,
    procedure and profile, and for a revision judged again the runs its last ``rejudge``
    step says it was judged against.

    A revision judged again before its ``rejudge`` step recorded those runs holds a hash no
    reader can recompute: it is left to its seal.
    """
    from storage.settings_hash import JUDGED_AGAINST, REJUDGE_STEP, settings_hash

    against: dict[int, list[str] | None] = {}  # a revision judged again twice: its last step
    for cal_id, step_settings in conn.execute(
        select(ProcessingStep.calibration_id, ProcessingStep.settings)
        .where(ProcessingStep.name == REJUDGE_STEP)
        .order_by(ProcessingStep.calibration_id, ProcessingStep.seq)
    ):
        against[cal_id] = (step_settings or {}).get(JUDGED_AGAINST)
    rows = conn.execution_options(yield_per=2000).execute(
        select(
            CalibrationRow.id,
            Run.run_id,
            Run.procedure,
            CalibrationRow.revision,
            CalibrationRow.settings_hash,
            CalibrationRow.settings,
            CalibrationRow.profile_name,
            CalibrationRow.profile_version,
        )
        .join(Run, Run.id == CalibrationRow.run_id)
        .order_by(CalibrationRow.id)
    )
    for r in rows:
        judged = r.id in against
        if judged and against[r.id] is None:
            continue
        expected = settings_hash(
            r.settings, r.procedure, r.profile_name, r.profile_version, against.get(r.id)
        )
        if expected == r.settings_hash:
            continue
        how = (
            f"judged again against {', '.join(against[r.id]) or 'no run'}"
            if judged
            else f"settings, procedure {r.procedure} and profile {r.profile_name} "
            f"v{r.profile_version}"
        )
        report.add(
            "record",
            f"calibrations/{r.revision}/settings_hash",
            [r.run_id],
            f"revision {r.revision} ({how}): settings hash {expected} expected, "
            f"{r.settings_hash} held",
        )


def _check_unit_latest(conn, report: VerifyReport) -> None:  # noqa: ANN001 - a Connection
    """The derived tables of each unit's picks and values (storage.unit_latest) against
    their derivation."""
    for d in unit_latest.differences(conn):
        report.add(
            "database",
            "",
            d["run_ids"],
            f"unit {d['serial']}: unit_latest holds {d['stored']}, "
            f"its runs give {d['derived']} (storage.unit_latest.rebuild derives it again)",
        )
    for d in unit_latest.value_differences(conn):
        report.add(
            "database",
            "",
            [],
            f"unit {d['serial']}: unit_latest_values of "
            f"{', '.join(d['names'])} differ from its latest valid calibration's parameters "
            f"({d['names'][0]}: {d['stored']} held, {d['derived']} derived)",
        )


def _check_seals(conn, root: Path, report: VerifyReport) -> None:  # noqa: ANN001 - a Connection
    from storage import approval, seal_check

    found = seal_check.check(conn, root)
    report.chain_head, report.seals_checked = found.head, found.seals_checked
    findings = found.findings + approval.check(conn, found.digests_now)
    report.problems += [Problem(f.kind, f.path, f.runs, f.detail) for f in findings]


def _check_store(archive: Archive, report: VerifyReport) -> None:
    """A PostgreSQL archive's files looked for in a folder that is not its file store
    (storage.store_identity): said once, before the files it then reports missing."""
    from storage import store_identity

    if archive.is_sqlite:
        return
    why = store_identity.mismatch(archive)
    if why:
        report.add("missing", "", [], why)


def _check_trust(
    conn,
    report: VerifyReport,
    approvers: Any,  # noqa: ANN001 - a Connection
    checkpoints: list[tuple[str, dict[str, Any]]],
) -> None:
    """Approvals against the lab's approvers file; the chain against each checkpoint."""
    from storage import approval, checkpoint

    findings = []
    if approvers is not None:
        report.approvers = str(approvers.source)
        findings += approval.check_trust(conn, approvers)
    for source, doc in checkpoints:
        report.checkpoints.append(source)
        findings += checkpoint.check(conn, doc, source)
        if approvers is not None and (why := checkpoint.untrusted_signer(doc, approvers)):
            report.add("checkpoint", source, [], why)
    report.problems += [Problem(f.kind, f.path, f.runs, f.detail) for f in findings]


_PARAMETER_FIELDS = ("value", "std", "unit")


def _check_parameters(conn, report: VerifyReport) -> None:  # noqa: ANN001 - a Connection
    """Every calibration's parameter rows against the parameters of its document."""
    rows: dict[int, dict[str, tuple]] = defaultdict(dict)
    for cal_id, name, *values in conn.execute(
        select(
            ParameterRow.calibration_id,
            ParameterRow.name,
            ParameterRow.value,
            ParameterRow.std,
            ParameterRow.unit,
        )
    ):
        if name in rows[cal_id]:
            report.add(
                "record",
                f"parameters/{name}",
                [],
                f"{name}: more than one parameters row in calibration id {cal_id}",
            )
        rows[cal_id][name] = tuple(values)
    docs = conn.execution_options(yield_per=2000).execute(
        select(CalibrationRow.id, CalibrationRow.revision, CalibrationRow.document, Run.run_id)
        .join(Run, Run.id == CalibrationRow.run_id)
        .order_by(CalibrationRow.id)
    )
    for cal_id, revision, document, run_id in docs:
        where = f"{run_id} revision {revision}"
        in_doc = (document or {}).get("parameters") or {}
        for detail in _parameter_differences(rows.pop(cal_id, {}), in_doc, where):
            name = detail.split(" ", 1)[0]
            report.add("record", f"parameters/{name}", [run_id], detail)
    for cal_id, stray in rows.items():
        for name in sorted(stray):
            report.add(
                "record",
                f"parameters/{name}",
                [],
                f"{name}: row of calibration id {cal_id}, which does not exist",
            )


def _parameter_differences(
    rows: dict[str, tuple], in_doc: dict[str, dict[str, Any]], where: str
) -> list[str]:
    """What differs between one calibration's rows (name -> (value, std, unit)) and document."""
    found: list[str] = []
    for name in sorted(set(rows) | set(in_doc)):
        if name not in in_doc:
            found.append(f"{name} of {where}: a parameters row, absent from the document")
            continue
        if name not in rows:
            found.append(f"{name} of {where}: in the document, no parameters row")
            continue
        for field_, row_value in zip(_PARAMETER_FIELDS, rows[name], strict=True):
            doc_value = in_doc[name].get(field_)
            if field_ == "unit":
                doc_value = doc_value or ""
            if row_value != doc_value:
                found.append(
                    f"{name} of {where}: {field_} is {row_value!r} in the parameters row, "
                    f"{doc_value!r} in the calibration document"
                )
    return found


def _orphans(root: Path, known_files: set[str], run_dirs: set[str]) -> list[str]:
    """Files under objects/ and samples/, and run folders, that the database does not list."""
    found: list[str] = []
    for top in ("objects", "samples"):
        base = root / top
        if base.is_dir():
            found += [
                rel
                for p in sorted(base.rglob("*"))
                if p.is_file() and (rel := p.relative_to(root).as_posix()) not in known_files
            ]
    runs = root / "runs"
    if runs.is_dir():
        # runs/<serial>/<day>/<run_id>: exactly three levels down
        for p in sorted(runs.glob("*/*/*")):
            rel = p.relative_to(root).as_posix()
            if p.is_dir() and rel not in run_dirs:
                found.append(rel + "/")
    return found
