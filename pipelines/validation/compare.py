"""Method validation, the comparison: an archived run's parameters against a peer's, with
the difference, the combined standard uncertainty and the normalised error E_n."""

from __future__ import annotations

from typing import Any

from storage.db import Archive

PEERS = ("imucal", "allantools")
K_EXPANDED = 2.0  # E_n is taken with expanded uncertainties U = k u_c, k = 2 (metrology.md)


def peer_names(text: str) -> tuple[str, ...]:
    """The peers named by ``--with`` (comma-separated); empty: every peer.

    Raises
    ------
    ValueError naming an unknown peer and the known ones.
    """
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in PEERS]
    if unknown:
        raise ValueError(f"--with: unknown peer {unknown[0]!r}; expected one of {', '.join(PEERS)}")
    return names or PEERS


def validate_run(archive: Archive, run_id: str, peers: tuple[str, ...]) -> dict[str, Any]:
    """One archived run compared with each peer in `peers`."""
    from storage import queries

    full = queries.full_run_id(archive, run_id)
    return {"run_id": full, "peers": [_unavailable(p, "comparison not yet built") for p in peers]}


def _unavailable(peer: str, reason: str) -> dict[str, Any]:
    return {"peer": peer, "status": "not compared", "reason": reason, "parameters": []}
