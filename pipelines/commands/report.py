"""`calib report RUN_ID`: the protocol and the issued certificate (HTML, PDF) of an archived run."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli_shared import ArchiveOpt, app, err, fail, fail_on, open_run, print_json


@app.command()
def report(
    run_id: str,
    archive: ArchiveOpt = None,
    pdf: Annotated[bool, typer.Option("--pdf/--no-pdf", help="Also hand out the PDF.")] = True,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Copy the files into this folder.")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the paths.")] = False,
    form: Annotated[
        str,
        typer.Option(
            "--format",
            help="certificate (protocol, HTML, PDF), pdf (the issued PDF alone) or dcc "
            "(Digital Calibration Certificate XML).",
        ),
    ] = "certificate",
    sign: Annotated[
        bool,
        typer.Option(
            "--sign",
            help="--format dcc: an enveloped XAdES signature; --format pdf: a PAdES signature; "
            "with the lab's key and certificate (lab.toml [signing]).",
        ),
    ] = False,
    reissue: Annotated[
        bool,
        typer.Option(
            "--reissue",
            help="Issue the certificate again from the archive "
            "as it is now (a new, sealed document).",
        ),
    ] = False,
    reason: Annotated[
        str | None, typer.Option("--reason", help="Why it is issued again (audit trail).")
    ] = None,
) -> None:
    """The test protocol and the certificate (HTML and PDF) issued when the run was archived.

    The files are the archived ones, sealed by the audit chain (`calib verify` rehashes
    them); --output copies them elsewhere. --reissue typesets the certificate again from
    the archive as it is now (after an approval, a new lab profile): a new document with
    its own number beside the earlier ones. A run archived before certificates were
    issued at archive time gets its first issue here. --format dcc writes the PTB DCC XML.
    --sign signs the DCC or the PDF for the customer (`calib verify-certificate` checks it);
    the signed copy goes to --output (default: the run's folder), the sealed issue stays.
    """
    from pipelines.reports.issue import issue, issued

    arch, run_id = open_run(archive, run_id)
    if reason is not None and not reissue:
        fail("--reason goes with --reissue (why the certificate is issued again)")
    if sign and form not in ("dcc", "pdf"):
        fail("--sign goes with --format dcc (XAdES) or --format pdf (PAdES)")
    try:
        if form == "pdf":
            written = _pdf(arch, run_id, output, sign, issue, issued)
        elif form != "certificate":
            from pipelines.reports.run_reports import report_run

            written = report_run(arch, run_id, output, pdf=pdf, form=form)
            if sign:
                written["dcc"] = _signed(written["dcc"], "dcc")
        else:
            current = None if reissue else issued(arch, run_id)
            if current is None:
                try:
                    current = issue(
                        arch, run_id, reason=reason or ("issued again" if reissue else None)
                    )
                except OSError as exc:
                    if output is None or reissue:
                        raise
                    written = _unissued_copy(arch, run_id, output, pdf, exc)
            if current is not None:
                files = {k: p for k, p in current.files.items() if pdf or k != "pdf"}
                if output is not None:
                    output.mkdir(parents=True, exist_ok=True)
                    files = {k: Path(shutil.copy2(p, output / p.name)) for k, p in files.items()}
                written = {"verdict": current.verdict, "certificate": current.number, **files}
    except (KeyError, LookupError, ValueError) as exc:
        fail(str(exc))
    except OSError as exc:  # a read-only archive, a full disk
        from storage.write_failures import describe

        fail(f"{describe(exc) or exc}; the reports can go elsewhere with --output DIR")
    verdict = written.pop("verdict")
    if as_json:
        print_json(
            {"run_id": run_id, "verdict": verdict, **{k: str(v) for k, v in written.items()}}
        )
        return
    number = written.pop("certificate", None)
    if number is not None:
        err.print(f"certificate {number}")
    for kind, path in written.items():
        err.print(f"{kind}: {path}")


def _signed(path: Path, kind: str) -> Path:
    """Sign the file at `path` in place (pipelines.reports.signing) with the lab's key."""
    from pipelines.reports import signing

    who = signing.lab_identity()
    sign = signing.sign_dcc if kind == "dcc" else signing.sign_pdf
    path.write_bytes(sign(path.read_bytes(), who))
    return path


def _pdf(arch, run_id: str, output: Path | None, sign: bool, issue, issued) -> dict:  # noqa: ANN001
    """The issued PDF (issued now when the run has none) copied out, signed with --sign: the
    archived, sealed file is never rewritten."""
    current = issued(arch, run_id) or issue(arch, run_id)
    source = current.files["pdf"]
    if output is None and not sign:
        return {"verdict": current.verdict, "certificate": current.number, "pdf": source}
    folder = output if output is not None else source.parent
    folder.mkdir(parents=True, exist_ok=True)
    name = source.name if not sign else source.name.replace(".pdf", "_signed.pdf")
    target = Path(shutil.copy2(source, folder / name))
    if sign:
        _signed(target, "pdf")
    return {"verdict": current.verdict, "certificate": current.number, "pdf": target}


@app.command("verify-certificate")
def verify_certificate(
    file: Path,
    certificate: Annotated[
        Path | None,
        typer.Option(help="The lab's certificate (PEM); default lab.toml [signing] certificate."),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the verdict as JSON.")] = False,
) -> None:
    """Check a signed DCC (XAdES) or PDF (PAdES) against the lab's certificate; say what changed.

    Exit 0 when the signature holds and covers the whole file, 1 when it does not."""
    from pipelines.reports import signing

    with fail_on(OSError, ValueError):
        cert = certificate or signing.lab_identity(need_key=False).certificate
        verdict = signing.verify(file.read_bytes(), cert.read_bytes())
    if as_json:
        print_json({"file": str(file), **verdict.__dict__})
    else:
        said = "VALID" if verdict.ok else "NOT VALID"
        err.print(
            f"{file}: {said} ({verdict.kind}, signed by {verdict.signer}): {verdict.detail}",
            markup=False,
        )
    if not verdict.ok:
        raise typer.Exit(1)


def _unissued_copy(arch, run_id: str, output: Path, pdf: bool, why: OSError) -> dict:  # noqa: ANN001
    """The reports rendered from the archive into `output` when the archive cannot take the
    certificate's first issue (read-only, full): said as not issued, nothing archived."""
    from pipelines.reports.run_reports import report_run
    from storage.write_failures import describe

    err.print(
        f"not issued: {describe(why) or why}; a rendering from the archive, not an "
        f"issued certificate, is written into {output}",
        markup=False,
    )
    return report_run(arch, run_id, output, pdf=pdf)
