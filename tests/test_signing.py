"""Signed certificates (docs/reports.md): `calib report RUN --format dcc --sign` (enveloped XAdES,
signxml) and `--format pdf --sign` (PAdES, pyHanko) with the lab's key and certificate of
lab.toml ``[signing]``; `calib verify-certificate FILE` checks them with those libraries'
verifiers. The PKI is made here with `cryptography` (a test CA, the lab's certificate it
issued, and a stranger's); the run is data_samples' MPU-6000 run, archived by the real pipeline
into a real SQLite file, its certificate issued."""

from __future__ import annotations

import base64
import datetime
import hashlib
import io
import re
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec, rsa
from cryptography.x509.oid import NameOID
from typer.testing import CliRunner

from calib_testing.archives import new_archive, processed_run
from calib_testing.documents import dcc_schema_errors
from calib_testing.lab_profile import CUBE, lab_toml
from pipelines.cli import app

DATA_SAMPLES = Path(__file__).resolve().parent.parent / "data_samples"
LAB_TOML = lab_toml(equipment=[CUBE], signing={"certificate": "lab-cert.pem", "key": "lab-key.pem"})


def _name(cn: str) -> x509.Name:
    return x509.Name(
        [
            x509.NameAttribute(NameOID.COMMON_NAME, cn),
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, "IMU Lab GmbH"),
        ]
    )


def _usage(*, ca: bool) -> x509.KeyUsage:
    return x509.KeyUsage(
        digital_signature=not ca,
        content_commitment=not ca,
        key_encipherment=False,
        data_encipherment=False,
        key_agreement=False,
        key_cert_sign=ca,
        crl_sign=ca,
        encipher_only=False,
        decipher_only=False,
    )


def _certificate(subject: str, key, issuer: x509.Name, issuer_key, *, ca: bool) -> x509.Certificate:  # noqa: ANN001
    now = datetime.datetime.now(datetime.UTC)
    return (
        x509.CertificateBuilder()
        .subject_name(_name(subject))
        .issuer_name(issuer)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(days=1))
        .not_valid_after(now + datetime.timedelta(days=30))
        .add_extension(x509.BasicConstraints(ca=ca, path_length=0 if ca else None), critical=True)
        .add_extension(_usage(ca=ca), critical=True)
        .sign(issuer_key, hashes.SHA256())
    )


def _write_identity(folder: Path, stem: str, key, cert: x509.Certificate) -> None:  # noqa: ANN001
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{stem}-key.pem").write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )
    )
    (folder / f"{stem}-cert.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))


@pytest.fixture(scope="module")
def lab(tmp_path_factory, issuing_certificates):
    """(archive, run id, profiles folder, a stranger's certificate) with the lab's PKI."""
    root = tmp_path_factory.mktemp("signing")
    ca_key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    ca = _certificate("Test CA", ca_key, _name("Test CA"), ca_key, ca=True)
    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    profiles = root / "profiles"
    _write_identity(
        profiles, "lab", key, _certificate("IMU Lab signing", key, ca.subject, ca_key, ca=False)
    )
    other = ec.generate_private_key(ec.SECP256R1())
    _write_identity(
        root / "other", "other", other, _certificate("Someone", other, ca.subject, ca_key, ca=False)
    )
    (profiles / "lab.toml").write_text(LAB_TOML)
    archive = new_archive(root)
    run_id = processed_run(DATA_SAMPLES / "mpu6000_MPU0001", archive)
    return archive, run_id, profiles, root / "other"


def _calib(*args: str):
    return CliRunner().invoke(app, [str(a) for a in args])


def _report(lab, tmp_path, form: str, monkeypatch) -> Path:
    archive, run_id, profiles, _ = lab
    monkeypatch.setenv("CALIB_PROFILES", str(profiles))
    res = _calib(
        "report",
        run_id,
        "--archive",
        archive.root,
        "--format",
        form,
        "--sign",
        "-o",
        tmp_path,
        "--json",
    )
    assert res.exit_code == 0, res.output
    import json

    return Path(json.loads(res.stdout)[form])


def _verify(path: Path, *more: str):
    res = _calib("verify-certificate", path, *more)
    return res.exit_code, " ".join(res.stderr.split())


def test_signed_dcc_verifies_and_is_still_schema_valid(lab, tmp_path, monkeypatch):
    path = _report(lab, tmp_path, "dcc", monkeypatch)
    data = path.read_bytes()
    assert b"<ds:Signature" in data and b"xades:QualifyingProperties" in data
    assert dcc_schema_errors(data) == []
    code, said = _verify(path)
    assert code == 0 and "VALID (dcc, signed by " in said and "CN=IMU Lab signing" in said


def _one_digit(text: str, where: str) -> str:
    """`text` with the last digit of the first value after `where` changed."""
    start = text.index(where)
    m = re.compile(r"<si:value>([^<]*\d)</si:value>").search(text, start)
    old = m.group(1)
    new = old[:-1] + ("1" if old[-1] != "1" else "2")
    return text[: m.start(1)] + new + text[m.end(1) :]


def test_an_altered_dcc_fails_naming_what_changed(lab, tmp_path, monkeypatch):
    path = _report(lab, tmp_path, "dcc", monkeypatch)
    text = path.read_text(encoding="utf-8")
    bad = tmp_path / "bad.xml"
    bad.write_text(_one_digit(text, 'id="result-gyr.bias.y"'), encoding="utf-8")
    code, said = _verify(bad)
    assert (
        code == 1
        and "NOT VALID" in said
        and "changed after signing: the result of gyr.bias.y" in said
    )
    bad.write_text(text.replace("<dcc:endPerformanceDate>2", "<dcc:endPerformanceDate>3", 1))
    code, said = _verify(bad)
    assert code == 1 and "the document outside the results" in said
    bad.write_text(text.replace("Example Drones AG", "Example Drones AH"))
    code, said = _verify(bad)
    assert code == 1 and "the customer" in said
    # the lab's certificate, not whoever signed: a stranger's certificate does not verify it
    _, _, _, other = lab
    code, said = _verify(path, "--certificate", other / "other-cert.pem")
    assert code == 1 and "not valid for this certificate" in said


def test_signed_pdf_verifies_and_an_altered_copy_fails(lab, tmp_path, monkeypatch):
    from pyhanko.pdf_utils import generic
    from pyhanko.pdf_utils.incremental_writer import IncrementalPdfFileWriter

    from pipelines.reports.issue import issued

    archive, run_id, *_ = lab
    sealed = issued(archive, run_id).files["pdf"]
    before = hashlib.sha256(sealed.read_bytes()).hexdigest()
    path = _report(lab, tmp_path, "pdf", monkeypatch)
    assert path.parent == tmp_path and path.name.endswith("_signed.pdf")
    assert hashlib.sha256(sealed.read_bytes()).hexdigest() == before  # the issue stays sealed
    code, said = _verify(path)
    assert code == 0 and "VALID (pdf" in said and "whole file is covered" in said

    data = bytearray(path.read_bytes())
    at = data.index(b"/Producer")  # a byte inside the signed range
    data[at + 2] ^= 0x01
    (tmp_path / "flip.pdf").write_bytes(bytes(data))
    code, said = _verify(tmp_path / "flip.pdf")
    assert code == 1 and "changed after signing: bytes of the signed file" in said

    writer = IncrementalPdfFileWriter(io.BytesIO(path.read_bytes()))
    writer.root["/Lang"] = generic.TextStringObject("de")  # an edit saved after signing
    writer.update_root()
    out = io.BytesIO()
    writer.write(out)
    (tmp_path / "later.pdf").write_bytes(out.getvalue())
    code, said = _verify(tmp_path / "later.pdf")
    assert code == 1 and "bytes added in a later revision" in said


def test_the_private_key_never_enters_the_archive(lab, tmp_path, monkeypatch):
    archive, run_id, profiles, _ = lab
    _report(lab, tmp_path, "dcc", monkeypatch)
    _report(lab, tmp_path, "pdf", monkeypatch)
    monkeypatch.setenv("CALIB_PROFILES", str(profiles))
    assert (
        _calib("report", run_id, "--archive", archive.root, "--format", "dcc", "--sign").exit_code
        == 0
    )
    # the key's secrets (d, p, q) in every form a file could carry them: raw, hex, base64 at
    # each of the three alignments, PEM (its public modulus is in the certificate, by design)
    pem = (profiles / "lab-key.pem").read_bytes()
    numbers = serialization.load_pem_private_key(pem, password=None).private_numbers()
    forms = [b"PRIVATE KEY"]
    for n in (numbers.d, numbers.p, numbers.q):
        raw = n.to_bytes((n.bit_length() + 7) // 8, "big")
        forms += [raw[8:-8], raw.hex().encode()[16:-16], raw.hex().upper().encode()[16:-16]]
        forms += [base64.b64encode(raw[k:])[8:-8] for k in range(3)]
    for file in [*archive.root.rglob("*"), *tmp_path.rglob("*")]:
        if file.is_file():
            data = file.read_bytes().replace(b"\n", b"").replace(b"\r", b"")
            assert not any(f in data for f in forms), file


def test_signing_without_the_lab_files_is_refused_naming_them(lab, tmp_path, monkeypatch):
    archive, run_id, profiles, _ = lab
    (tmp_path / "lab.toml").write_text(lab_toml(equipment=[CUBE]))
    monkeypatch.setenv("CALIB_PROFILES", str(tmp_path))
    res = _calib(
        "report", run_id, "--archive", archive.root, "--format", "dcc", "--sign", "-o", tmp_path
    )
    assert res.exit_code == 2 and "no [signing] table in the lab profile" in " ".join(
        res.stderr.split()
    )
    res = _calib("report", run_id, "--archive", archive.root, "--sign")
    assert res.exit_code == 2 and "--sign goes with --format dcc" in " ".join(res.stderr.split())
