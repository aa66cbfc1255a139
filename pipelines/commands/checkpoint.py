"""`calib checkpoint`: the audit chain's head written to a file kept outside the archive."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli_shared import ArchiveOpt, app, err, fail, open_archive


@app.command()
def checkpoint(
    output: Annotated[Path, typer.Option("--output", "-o", help="New checkpoint file.")],
    key: Annotated[
        Path | None, typer.Option("--key", help="Sign it with this key (calib keygen).")
    ] = None,
    archive: ArchiveOpt = None,
) -> None:
    """Write the audit chain's head (event number, hash, time, counts of runs and seals) to a
    new file; keep it where the archive's writers cannot reach it, and check the archive
    against it with `calib verify --checkpoint FILE`."""
    import json

    from pipelines.commands.audit import read_passphrase
    from storage import checkpoint as checkpoints
    from storage.approval import ApprovalError, load_key

    if output.exists():
        fail(f"{output} exists already; a checkpoint is never overwritten")
    arch = open_archive(archive)
    signing, signer = None, None
    if key is not None:
        pub = key.with_name(key.name + ".pub")
        try:
            signer = json.loads(pub.read_text())["name"]
            signing = load_key(key, read_passphrase(confirm=False))
        except (OSError, ValueError, KeyError) as exc:
            fail(f"{pub}: cannot read the signer's name ({exc})")
        except ApprovalError as exc:
            fail(str(exc))
    doc = checkpoints.make(arch, signing, signer)
    try:
        checkpoints.write(doc, output)
    except OSError as exc:
        fail(f"{output}: cannot be written ({exc.strerror or exc})")
    signed = f", signed by {signer}" if signer else ""
    err.print(
        f"checkpoint of event {doc['seq']} (hash {doc['hash']}; {doc['runs']} runs, "
        f"{doc['seals']} seals) written to {output}{signed}"
    )
