"""Trusted approvers (storage.approval.Approvers, pipelines.trust) and checkpoints
(storage.checkpoint): the two attacks a hash chain alone lets through.

Known truth: the keys made here and the runs `fill` archived. The forged approval
is made as an attacker would, with calib's own code: a new key in the approver's
name, signed through `calib approve` and, with a database writer's rights, as an
event appended directly with a date inside the real key's validity. The full
rewrite and the rollback are made with calib's own sealing and chaining code, so
`calib verify` without a checkpoint reports OK for both (asserted): only the
checkpoint can tell.
"""

from __future__ import annotations

import json
import re
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from sqlalchemy import select, text
from test_seal import behind_the_archive
from test_verify_backup import cli, fill

from pipelines.trust import approval_line
from storage import checkpoint, seal, seal_record, unit_latest
from storage.approval import (
    approvals,
    approve,
    fingerprint,
    generate_key,
    load_approvers,
    load_key,
    message,
)
from storage.current import CURRENT
from storage.db import Archive
from storage.schema import AuditEvent, CalibrationRow, ParameterRow, Run, Seal
from storage.verify import verify

PASS = "correct horse battery"
JANE = "Jane Approver"


def _key(folder: Path, file: str, name: str) -> Path:
    folder.mkdir(exist_ok=True)
    generate_key(folder / file, name, PASS)
    return folder / file


def _approvers(tmp: Path, *pubs: Path, **extra: str) -> Path:
    """`cat a.pub b.pub > approvers`, with `extra` fields added to every line."""
    lines = [json.dumps({**json.loads(p.read_text()), **extra}) for p in pubs]
    path = tmp / "approvers"
    path.write_text("# the lab's approvers\n" + "\n".join(lines) + "\n")
    return path


@pytest.fixture
def keys(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, Path]:
    monkeypatch.setenv("CALIB_KEY_PASSPHRASE", PASS)
    monkeypatch.delenv("CALIB_APPROVERS", raising=False)
    jane = _key(tmp_path / "jane", "jane.key", JANE)
    mallory = _key(tmp_path / "mallory", "forged.key", JANE)  # the same name, another key
    return {
        "jane": jane,
        "forged": mallory,
        "approvers": _approvers(tmp_path, jane.with_name("jane.key.pub")),
    }


def test_a_forged_approval_is_flagged_and_a_trusted_one_verifies(
    archive: Archive, tmp_path: Path, keys: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    ids = fill(archive, tmp_path)
    approvers = str(keys["approvers"])
    res = cli(archive, "approve", ids[0], "--key", str(keys["jane"]), monkeypatch=monkeypatch)
    assert res.exit_code == 0, res.output
    res = cli(archive, "verify", "--no-orphans", "--approvers", approvers, monkeypatch=monkeypatch)
    assert res.exit_code == 0, res.output
    assert f"approvals checked against {approvers}" in res.stderr

    # The attack: a new key named "Jane Approver", and `calib approve` of the failing run.
    res = cli(archive, "approve", ids[1], "--key", str(keys["forged"]), monkeypatch=monkeypatch)
    assert res.exit_code == 0, res.output
    assert verify(archive, orphans=False).ok  # without the approvers file nothing tells
    res = cli(archive, "verify", "--no-orphans", monkeypatch=monkeypatch)
    assert res.exit_code == 0 and "not checked against a list of trusted approvers" in res.stderr
    forged_fp = fingerprint(
        json.loads(keys["forged"].with_name("forged.key.pub").read_text())["public_key"]
    )
    res = cli(archive, "verify", "--no-orphans", "--approvers", approvers, monkeypatch=monkeypatch)
    assert res.exit_code == 1, res.output
    (line,) = [x for x in res.stdout.splitlines() if x.startswith("UNTRUSTED")]
    assert ids[1] in line and f"claimed by {JANE}" in line and forged_fp in line, line
    assert "not in the approvers file" in line

    # audit and show mark it untrusted instead of "approved by"; the trusted one stays.
    res = cli(archive, "audit", "--approvers", approvers, monkeypatch=monkeypatch)
    (forged,) = [x for x in res.stdout.splitlines() if ids[1] in x and "\tapproved\t" in x]
    assert f"UNTRUSTED approved claimed by {JANE}" in forged and "approved by" not in forged
    (real,) = [x for x in res.stdout.splitlines() if ids[0] in x and "\tapproved\t" in x]
    assert f"approved by {JANE}" in real and "not checked" not in real
    monkeypatch.setenv("CALIB_APPROVERS", approvers)
    res = cli(archive, "show", ids[1], monkeypatch=monkeypatch)
    assert res.exit_code == 0, res.output
    assert f"UNTRUSTED approved claimed by {JANE}" in res.stdout
    assert f"approved by {JANE}" not in res.stdout


def test_a_forged_event_with_writer_rights_is_flagged(
    archive: Archive, tmp_path: Path, keys: dict[str, Path]
) -> None:
    """With a database writer's rights, the forger appends the approval event directly, dated
    inside the real key's validity: the key still is not the lab's."""
    ids = fill(archive, tmp_path)
    pub = keys["jane"].with_name("jane.key.pub")
    trusted = load_approvers(
        _approvers(tmp_path, pub, valid_from="2020-01-01", valid_until="2020-12-31")
    )
    forged = load_key(keys["forged"], PASS)
    public = forged.public_key().public_bytes_raw().hex()
    with behind_the_archive(archive) as conn:
        digest = conn.execute(
            select(Seal.digest)
            .join(CalibrationRow, CalibrationRow.id == Seal.calibration_id)
            .join(Run, Run.id == CalibrationRow.run_id)
            .where(Run.run_id == ids[2])
        ).scalar_one()
        sig = forged.sign(message(ids[2], 1, digest, "approved", JANE, public)).hex()
        seq, prev = seal.head(conn)
        ev = seal.Event(
            seq + 1,
            datetime(2020, 6, 1, tzinfo=UTC),
            "jane",
            "approved",
            ids[2],
            1,
            None,
            {"meaning": "approved", "signer": JANE, "public_key": public, "signature": sig},
            digest,
            prev,
        )
        conn.execute(
            AuditEvent.__table__.insert().values(
                **{k: getattr(ev, k) for k in seal.EVENT_FIELDS}, hash=ev.hash()
            )
        )
    assert verify(archive, orphans=False).ok  # linked and signed: the chain cannot tell
    report = verify(archive, orphans=False, approvers=trusted)
    (p,) = report.problems
    assert p.kind == "untrusted" and p.runs == [ids[2]] and fingerprint(public) in p.detail


def test_validity_dates_and_roles_of_the_approvers_file(
    archive: Archive, tmp_path: Path, keys: dict[str, Path]
) -> None:
    ids = fill(archive, tmp_path)
    pub = keys["jane"].with_name("jane.key.pub")
    approve(archive, ids[0], load_key(keys["jane"], PASS), signer=JANE)
    today = datetime.now(UTC).date()
    expired = load_approvers(_approvers(tmp_path, pub, valid_until=str(today - timedelta(1))))
    (a,) = approvals(archive, ids[0], expired)
    assert a.trusted is False and f"not on {today}" in a.untrusted
    assert approval_line(a).startswith("UNTRUSTED approved claimed by")
    reviewer = load_approvers(_approvers(tmp_path, pub, role="reviewer"))
    assert "may not sign 'approved'" in approvals(archive, ids[0], reviewer)[0].untrusted
    current = load_approvers(_approvers(tmp_path, pub, valid_from=str(today)))
    (a,) = approvals(archive, ids[0], current)
    assert a.trusted is True and approval_line(a).startswith(f"approved by {JANE}")
    (a,) = approvals(archive, ids[0])
    assert a.trusted is None and "not checked" in approval_line(a)


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("not json", "line 2: expected one JSON object"),
        ('{"name": "A"}', "line 2: public_key: required field is missing"),
        ("[1, 2]", r"line 2: \(top level\): expected a table \(an object\), got \[1, 2\]"),
        ('{"name": 3, "public_key": "' + "ab" * 32 + '"}', "line 2: name: expected text, got 3"),
        ('{"name": "A", "public_key": NaN}', "line 2: public_key: expected text, got nan"),
        (
            '{"name": "A\\u0007", "public_key": "' + "ab" * 32 + '"}',
            "line 2: name: expected one line",
        ),
        (
            '{"name": "A", "public_key": "' + "ab" * 32 + '", "rol": 1}',
            "line 2: rol: unknown field",
        ),
        (
            '{"name": "A", "public_key": "' + "ab" * 32 + '", "valid_from": "2024-02-01", '
            '"valid_until": "2024-01-31"}',
            "line 2: valid_until: expected a day on or after valid_from 2024-02-01, got 2024-01-31",
        ),
        ('{"name": "A", "public_key": "zz"}', "line 2: public_key: expected 64 hex digits"),
        (
            '{"name": "A", "public_key": "' + "ab" * 32 + '", "valid_from": "2024-13-01"}',
            "line 2: valid_from: expected a date YYYY-MM-DD",
        ),
        (
            '{"name": "A", "public_key": "' + "ab" * 32 + '", "role": "boss"}',
            "line 2: role must be one of 'approver', 'reviewer', got 'boss'",
        ),
    ],
)
def test_a_bad_approvers_file_is_named_by_line(tmp_path: Path, line: str, expected: str) -> None:
    path = tmp_path / "approvers"
    path.write_text("# header\n" + line + "\n")
    with pytest.raises(ValueError, match=expected):
        load_approvers(path)


def test_lab_toml_names_the_approvers_file(
    tmp_path: Path, keys: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    from pipelines.trust import approvers_file

    profiles = tmp_path / "profiles"
    profiles.mkdir()
    (profiles / "lab.toml").write_text('[trust]\napprovers = "approvers"\n')
    monkeypatch.setenv("CALIB_PROFILES", str(profiles))
    assert approvers_file() == profiles / "approvers"
    monkeypatch.setenv("CALIB_APPROVERS", str(keys["approvers"]))
    assert approvers_file() == keys["approvers"]  # the environment before lab.toml
    assert approvers_file(tmp_path / "x") == tmp_path / "x"  # the command line first


# --- checkpoints -------------------------------------------------------------------


def _checkpoint(
    archive: Archive, tmp: Path, monkeypatch: pytest.MonkeyPatch, key: Path | None = None
) -> Path:
    tmp.mkdir(exist_ok=True)
    path = tmp / "checkpoint.json"
    args = ["checkpoint", "-o", str(path)] + (["--key", str(key)] if key else [])
    res = cli(archive, *args, monkeypatch=monkeypatch)
    assert res.exit_code == 0, res.output
    return path


def _verify_against(archive: Archive, cp: Path, monkeypatch: pytest.MonkeyPatch):  # noqa: ANN202
    return cli(archive, "verify", "--no-orphans", "--checkpoint", str(cp), monkeypatch=monkeypatch)


def test_the_chain_extends_its_checkpoint(
    archive: Archive, tmp_path: Path, keys: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    ids = fill(archive, tmp_path)
    cp = _checkpoint(archive, tmp_path, monkeypatch, keys["jane"])
    doc = json.loads(cp.read_text())
    assert (doc["seq"], doc["runs"], doc["seals"], doc["signer"]) == (4, 3, 4, JANE)
    approve(archive, ids[0], load_key(keys["jane"], PASS), signer=JANE)  # the chain grows
    res = _verify_against(archive, cp, monkeypatch)
    assert res.exit_code == 0, res.output
    assert f"chain compared with the checkpoint {cp}" in res.stderr
    res = cli(
        archive,
        "verify",
        "--no-orphans",
        "--checkpoint",
        str(cp),
        "--approvers",
        str(keys["approvers"]),
        monkeypatch=monkeypatch,
    )  # signed by a trusted key
    assert res.exit_code == 0, res.output
    forged = _checkpoint(archive, tmp_path / "f", monkeypatch, keys["forged"])
    res = cli(
        archive,
        "verify",
        "--no-orphans",
        "--checkpoint",
        str(forged),
        "--approvers",
        str(keys["approvers"]),
        monkeypatch=monkeypatch,
    )
    assert res.exit_code == 1
    assert f"the checkpoint is signed by {JANE}, not trusted" in res.stdout
    res = cli(archive, "checkpoint", "-o", str(cp), monkeypatch=monkeypatch)
    assert res.exit_code == 2 and "never overwritten" in res.output
    doc["runs"] = 2  # the signed file altered
    cp.write_text(json.dumps(doc))
    res = _verify_against(archive, cp, monkeypatch)
    assert res.exit_code == 1 and "does not verify" in res.stdout


def _rewrite_value(archive: Archive, run_id: str) -> None:
    """The full-rewrite attack with calib's own code: a parameter and its document
    changed, the seal made again, every event from there on rehashed."""
    with behind_the_archive(archive) as conn:
        cal_id = conn.execute(
            select(CalibrationRow.id)
            .join(Run, Run.id == CalibrationRow.run_id)
            .where(Run.run_id == run_id, CURRENT)
        ).scalar_one()
        name, value = conn.execute(
            select(ParameterRow.name, ParameterRow.value)
            .where(ParameterRow.calibration_id == cal_id)
            .order_by(ParameterRow.name)
            .limit(1)
        ).one()
        doc = conn.execute(
            select(CalibrationRow.document).where(CalibrationRow.id == cal_id)
        ).scalar_one()
        doc["parameters"][name]["value"] = value + 0.5
        conn.execute(
            ParameterRow.__table__.update()
            .where(ParameterRow.calibration_id == cal_id, ParameterRow.name == name)
            .values(value=value + 0.5)
        )
        conn.execute(
            CalibrationRow.__table__.update()
            .where(CalibrationRow.id == cal_id)
            .values(document=doc)
        )
        files = conn.execute(select(Seal.record).where(Seal.calibration_id == cal_id)).scalar_one()
        conn.execute(Seal.__table__.delete().where(Seal.calibration_id == cal_id))
        rec = seal_record.records(conn, [cal_id], {cal_id: files["files"]})[cal_id]
        digest = seal.insert_seal(conn, cal_id, rec)
        rows = conn.execute(select(AuditEvent).order_by(AuditEvent.seq)).all()
        conn.execute(AuditEvent.__table__.delete())
        prev = seal.GENESIS
        for row in rows:
            ev = seal.Event(**{k: getattr(row, k) for k in seal.EVENT_FIELDS})
            if ev.run_id == run_id and ev.digest is not None and ev.action in seal.SEALING:
                ev = seal.Event(**{**ev.__dict__, "digest": digest})
            ev = seal.Event(**{**ev.__dict__, "prev_hash": prev})
            prev = ev.hash()
            conn.execute(
                AuditEvent.__table__.insert().values(
                    **{k: getattr(ev, k) for k in seal.EVENT_FIELDS}, hash=prev
                )
            )
        unit_latest.rebuild(conn)  # the derived copy of the value, as verify expects it


def test_a_checkpoint_dated_by_a_number_is_judged_not_crashed(
    archive: Archive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`at` is not declared (the date is shown, not trusted): a number there is shown as
    found and the chain still judged against the checkpoint."""
    ids = fill(archive, tmp_path)
    cp = _checkpoint(archive, tmp_path, monkeypatch)
    _rewrite_value(archive, ids[1])
    cp.write_text(json.dumps({**json.loads(cp.read_text()), "at": 20261202}))
    res = _verify_against(archive, cp, monkeypatch)
    assert res.exit_code == 1, res.output
    (line,) = [x for x in res.stdout.splitlines() if x.startswith("CHECKPOINT")]
    assert "20261202" in line and "differs from the checkpoint" in line, line


def test_a_full_rewrite_is_caught_by_the_checkpoint(
    archive: Archive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ids = fill(archive, tmp_path)
    cp = _checkpoint(archive, tmp_path, monkeypatch)
    _rewrite_value(archive, ids[1])  # archived by event 2
    assert verify(archive, orphans=False).ok  # the rewrite verifies without the checkpoint
    res = _verify_against(archive, cp, monkeypatch)
    assert res.exit_code == 1, res.output
    (line,) = [x for x in res.stdout.splitlines() if x.startswith("CHECKPOINT")]
    assert f"event 2 (archived of {ids[1]}) differs from the checkpoint" in line, line


def test_a_rollback_is_caught_by_the_checkpoint(
    archive: Archive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The newest run deleted with its seal and events, the derived tables rebuilt."""
    ids = fill(archive, tmp_path)
    cp = _checkpoint(archive, tmp_path, monkeypatch)
    victim = ids[2]  # archived by event 3; event 4 revises ids[0]: both go
    with behind_the_archive(archive) as conn:
        cal = "SELECT id FROM calibrations WHERE run_id = (SELECT id FROM runs WHERE run_id = :r)"
        conn.execute(text("DELETE FROM audit_events WHERE seq >= 3"))
        gone = f"calibration_id IN ({cal}) OR calibration_id = (SELECT max(id) FROM calibrations)"
        for t in ("seals", "parameters", "check_results", "processing_steps"):
            conn.execute(text(f"DELETE FROM {t} WHERE {gone}"), {"r": victim})
        conn.execute(
            text(
                "UPDATE calibrations SET superseded_by = NULL WHERE superseded_by = "
                "(SELECT max(id) FROM calibrations)"
            )
        )
        conn.execute(text("DELETE FROM calibrations WHERE id = (SELECT max(id) FROM calibrations)"))
        conn.execute(text(f"DELETE FROM calibrations WHERE id IN ({cal})"), {"r": victim})
        for t in ("raw_files", "run_equipment"):
            conn.execute(
                text(f"DELETE FROM {t} WHERE run_id = (SELECT id FROM runs WHERE run_id = :r)"),
                {"r": victim},
            )
        conn.execute(text("DELETE FROM runs WHERE run_id = :r"), {"r": victim})
        unit_latest.rebuild(conn)
    report = verify(archive, orphans=False)
    assert report.ok, report.problems  # the rollback verifies without the checkpoint
    res = _verify_against(archive, cp, monkeypatch)
    assert res.exit_code == 1, res.output
    (line,) = [x for x in res.stdout.splitlines() if x.startswith("CHECKPOINT")]
    assert "events 3..4 of the checkpoint" in line and "rollback or truncation" in line, line


HEAD = '"kind": "calib-checkpoint", "version": 1'


@pytest.mark.parametrize(
    ("doc", "expected"),
    [
        ('{"kind": "something else"}', "kind: expected 'calib-checkpoint'"),
        ("[1]", r"\(top level\): expected an object of kind 'calib-checkpoint', got \[1\]"),
        (
            "{" + HEAD + ', "seq": 2, "hash": "x", "events": ["a"]}',
            "events: expected one hash prefix per event up to seq 2, got 1",
        ),  # fmt: skip
        (
            '{"kind": "calib-checkpoint", "version": 2, "seq": 0, "hash": "x", "events": []}',
            "version: expected 1 .*, got 2",
        ),  # fmt: skip
        ("{" + HEAD + ', "seq": 1, "events": ["a"]}', "hash: required field is missing"),
        ("{" + HEAD + ', "seq": "1", "hash": "x", "events": ["a"]}', "seq: expected .*, got '1'"),
        ("{" + HEAD + ', "seq": NaN, "hash": "x", "events": []}', "seq: expected .*, got nan"),
        ("{" + HEAD + ', "seq": 1, "hash": "x", "events": [7]}', r"events\[0\]: expected .*got 7"),
    ],
)
def test_checkpoint_files_are_checked(tmp_path: Path, doc: str, expected: str) -> None:
    """Refused naming the file and the key (a JSON document: its key path, no line), what
    was expected and what was found."""
    path = tmp_path / "cp.json"
    path.write_text(doc)
    with pytest.raises(ValueError, match=f"^checkpoint {re.escape(str(path))}: {expected}"):
        checkpoint.load(path)


def test_the_certificate_marks_an_untrusted_approval_and_prints_the_chain_head(
    archive: Archive, tmp_path: Path, keys: dict[str, Path]
) -> None:
    """The certificate's signatures: the forged approval is UNTRUSTED and does not approve;
    the chain head at issue is printed; without a file it says approvals were not checked."""
    from pipelines.reports.signatures import signatures_section

    ids = fill(archive, tmp_path)
    approve(archive, ids[0], load_key(keys["forged"], PASS), signer=JANE)
    trust = load_approvers(keys["approvers"])
    with archive.engine().connect() as conn:
        head = seal.head(conn)
    from storage.approval import approval_status

    marked = approval_status(archive, ids[0], 2, trust)  # the current revision of ids[0]
    pairs = dict(signatures_section(None, head, marked).pairs)
    assert pairs["UNTRUSTED, claimed approved"].startswith(f"{JANE}, ")
    assert "is not in the approvers file" in pairs["UNTRUSTED, claimed approved"]
    assert pairs["Electronic approval"].startswith("NOT APPROVED")
    assert pairs["Audit chain at issue"] == f"event {head[0]}, hash {head[1]}"
    unchecked = dict(signatures_section(None, head, approval_status(archive, ids[0], 2)).pairs)
    assert "Electronically approved" in unchecked and "Electronic approval" not in unchecked
    assert "not checked" in unchecked["Approvers"]
