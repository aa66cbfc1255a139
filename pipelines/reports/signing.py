"""Signed certificates: the DCC with an enveloped XAdES signature (signxml), the PDF with a
PAdES signature (pyHanko), made with the lab's X.509 key and certificate that lab.toml names::

    [signing]
    certificate = "lab-cert.pem"    # PEM, beside lab.toml (or an absolute path)
    key = "lab-key.pem"             # PEM private key, unencrypted; read when signing only

The key is read from its file when a document is signed and goes nowhere else: not into the
archive, not into the signed file (which carries the certificate). `verify` checks a signed
file against the lab's certificate and says what changed: for a DCC the signature holds one
reference per result (``id="result-<parameter>"``), the item, the customer and the whole
document, so a digest that no longer matches names the part that changed; for a PDF, pyHanko
reports bytes altered inside the signed range or a revision added after signing.
"""

from __future__ import annotations

import hashlib
import io
import logging
from dataclasses import dataclass
from pathlib import Path

SIGNING_TABLE = "signing"
PDF_FIELD = "LabSignature"


@dataclass(frozen=True)
class Identity:
    """The lab's signing key and certificate files."""

    key: Path
    certificate: Path


@dataclass(frozen=True)
class Verdict:
    """What `verify` found: ``ok``, the kind (``dcc`` / ``pdf``), who signed, what changed."""

    ok: bool
    kind: str
    signer: str
    detail: str


def lab_identity(*, need_key: bool = True) -> Identity:
    """The [signing] files of the lab profile. Raises ValueError naming the missing field."""
    from pipelines.lab import load_lab_profile

    found = load_lab_profile()
    if found is None or SIGNING_TABLE not in found[0]:
        raise ValueError(
            "no [signing] table in the lab profile lab.toml (CALIB_PROFILES): it names the "
            'lab\'s certificate = "FILE.pem" and key = "FILE.pem"'
        )
    doc, path = found
    table = doc[SIGNING_TABLE]
    files = {k: (path.parent / table[k]) for k in ("key", "certificate")}
    for kind, file in files.items():
        if not (need_key or kind == "certificate") or file.is_file():
            continue
        raise ValueError(f"lab profile {path}: signing.{kind}: no file {file}")
    return Identity(files["key"], files["certificate"])


def _subject(cert_pem: bytes) -> str:
    from cryptography import x509

    return x509.load_pem_x509_certificate(cert_pem).subject.rfc4514_string()


# --- DCC: XAdES ---------------------------------------------------------------------------


def _references(root) -> list[str]:  # noqa: ANN001 - lxml element
    """The reference URIs of a DCC's signature: each part with an id, then the document."""
    from pipelines.reports.dcc import DCC_NS

    parts = [
        el.get("id")
        for el in root.iter(f"{{{DCC_NS}}}result", f"{{{DCC_NS}}}items", f"{{{DCC_NS}}}customer")
        if el.get("id")
    ]
    return [f"#{p}" for p in parts] + [""]


def _signer_class() -> type:
    """signxml's XAdESSigner, taking the whole-document reference ``URI=""`` beside ``#id``
    ones (signxml resolves a list's "" as "#"; a lone "" is its default, the document)."""
    from signxml.xades import XAdESSigner

    class DccSigner(XAdESSigner):
        def _get_c14n_inputs_from_references(self, doc_root, references):  # noqa: ANN001, ANN202
            parts = [r for r in references if r.URI != ""]
            whole = [r for r in references if r.URI == ""]
            inputs, refs = super()._get_c14n_inputs_from_references(doc_root, parts)
            return inputs + [self.get_root(doc_root) for _ in whole], refs + whole

    return DccSigner


def sign_dcc(xml: bytes, who: Identity) -> bytes:
    """The DCC with an enveloped XAdES-BES signature appended to its root (ds:Signature, which
    DCC 3.3.0 allows there), RSA or ECDSA with SHA-256, the certificate in KeyInfo."""
    from lxml import etree
    from signxml import SignatureMethod, methods

    root = etree.fromstring(xml, etree.XMLParser(resolve_entities=False, no_network=True))
    key, cert = who.key.read_bytes(), who.certificate.read_bytes()
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.hazmat.primitives.serialization import load_pem_private_key

    is_rsa = isinstance(load_pem_private_key(key, password=None), rsa.RSAPrivateKey)
    algorithm = SignatureMethod.RSA_SHA256 if is_rsa else SignatureMethod.ECDSA_SHA256
    signer = _signer_class()(method=methods.enveloped, signature_algorithm=algorithm)
    signed = signer.sign(root, key=key, cert=cert, reference_uri=_references(root))
    return etree.tostring(signed, xml_declaration=True, encoding="UTF-8")


def _verify_dcc(data: bytes, cert_pem: bytes) -> Verdict:
    from lxml import etree
    from signxml.exceptions import InvalidDigest, InvalidInput, InvalidSignature
    from signxml.xades import XAdESSignatureConfiguration, XAdESVerifier

    root = etree.fromstring(data, etree.XMLParser(resolve_entities=False, no_network=True))
    refs = _references(root)
    config = XAdESSignatureConfiguration(expect_references=len(refs) + 2)
    signer = _subject(cert_pem)
    if root.find("{http://www.w3.org/2000/09/xmldsig#}Signature") is None:
        return Verdict(False, "dcc", signer, "no signature in the document (ds:Signature)")
    try:
        XAdESVerifier().verify(data, x509_cert=cert_pem.decode(), expect_config=config)
    except InvalidDigest as exc:  # "Digest mismatch for reference N (URI)"
        uri = str(exc).rsplit("(", 1)[-1].rstrip(")")
        return Verdict(False, "dcc", signer, f"changed after signing: {_part(uri)}")
    except (InvalidSignature, InvalidInput) as exc:
        return Verdict(False, "dcc", signer, f"signature not valid for this certificate: {exc}")
    return Verdict(True, "dcc", signer, f"intact: {len(refs)} signed parts unchanged")


def _part(uri: str) -> str:
    """The DCC part a reference URI names, in words."""
    if uri.startswith("#result-"):
        return f"the result of {uri.removeprefix('#result-')}"
    if uri in ("#items", "#customer"):
        return f"the {uri[1:]} ({'the calibrated item' if uri == '#items' else 'customer'})"
    return (
        "the document outside the results, item and customer (administrative data, the signature)"
    )


# --- PDF: PAdES ---------------------------------------------------------------------------


def sign_pdf(pdf: bytes, who: Identity, *, reason: str = "Calibration certificate") -> bytes:
    """The PDF with a PAdES (ETSI.CAdES.detached) signature in an incremental revision."""
    from pyhanko.pdf_utils.incremental_writer import IncrementalPdfFileWriter
    from pyhanko.sign import fields, signers

    signer = signers.SimpleSigner.load(str(who.key), str(who.certificate))
    if signer is None:
        raise ValueError(f"cannot load the signing key {who.key} with {who.certificate}")
    meta = signers.PdfSignatureMetadata(
        field_name=PDF_FIELD, subfilter=fields.SigSeedSubFilter.PADES, reason=reason
    )
    out = signers.sign_pdf(IncrementalPdfFileWriter(io.BytesIO(pdf)), meta, signer=signer)
    return out.getvalue()


def _verify_pdf(data: bytes, cert_pem: bytes) -> Verdict:
    from asn1crypto import pem, x509
    from pyhanko.pdf_utils.reader import PdfFileReader
    from pyhanko.sign.validation import validate_pdf_signature
    from pyhanko.sign.validation.errors import SignatureValidationError
    from pyhanko_certvalidator import ValidationContext

    signer = _subject(cert_pem)
    sigs = PdfFileReader(io.BytesIO(data), strict=False).embedded_signatures
    if not sigs:
        return Verdict(False, "pdf", signer, "no signature in the PDF")
    lab = x509.Certificate.load(pem.unarmor(cert_pem)[2])
    context = ValidationContext(trust_roots=[lab], allow_fetching=False)
    quiet = logging.getLogger("pyhanko")
    level, quiet.level = quiet.level, logging.CRITICAL  # its diff analysis logs tracebacks
    try:
        status = validate_pdf_signature(sigs[-1], context)
    except SignatureValidationError as exc:
        return Verdict(False, "pdf", signer, f"signature not valid: {exc}")
    finally:
        quiet.setLevel(level)
    if status.signing_cert.sha256 != lab.sha256:
        who = status.signing_cert.subject.human_friendly
        return Verdict(False, "pdf", who, f"signed by {who}, not by the lab's certificate")
    if not status.intact:
        return Verdict(False, "pdf", signer, "changed after signing: bytes of the signed file")
    if not status.valid:
        return Verdict(False, "pdf", signer, "signature not valid for this certificate")
    covered = status.coverage.name
    if covered != "ENTIRE_FILE":
        level = getattr(status.modification_level, "name", "unknown")
        _, len1, start2, len2 = sigs[-1].byte_range
        added = len(data) - (start2 + len2)
        return Verdict(
            False,
            "pdf",
            signer,
            f"changed after signing: {added} bytes added in a later revision "
            f"(pyHanko: coverage {covered}, modification level {level})",
        )
    return Verdict(True, "pdf", signer, "intact: the whole file is covered by the signature")


def verify(data: bytes, cert_pem: bytes) -> Verdict:
    """Check a signed DCC (XML) or PDF against the lab's certificate (PEM)."""
    if data.startswith(b"%PDF"):
        return _verify_pdf(data, cert_pem)
    if data.lstrip().startswith(b"<"):
        return _verify_dcc(data, cert_pem)
    digest = hashlib.sha256(data).hexdigest()[:16]
    raise ValueError(f"neither a PDF nor an XML document (sha256 {digest}...)")
