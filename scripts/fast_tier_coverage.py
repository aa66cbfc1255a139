"""Does the fast tier (`make test-fast`) still cover every package and every procedure?

Runs the tier as the Makefile does (its marker expression, both cores) with the plugin
calib_testing.tier_coverage, then lists each procedure of calib_core.procedures.ALL with
the number of the tier's tests that solve it, and each package of the project with the
number of its modules the tests loaded. Exits 1 naming what nothing in the tier reaches
(a test marked slow that was the last of its kind), or when the tier fails.

    PYTHONPATH=. .venv/bin/python scripts/fast_tier_coverage.py [extra pytest arguments]
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def fast_marker() -> str:
    """The Makefile's FAST marker expression (one definition of the tier)."""
    text = (ROOT / "Makefile").read_text(encoding="utf-8")
    return re.search(r"^FAST\s*=\s*(.+)$", text, re.M).group(1).strip()


def packages() -> list[str]:
    """Every package of the project (a folder with an __init__.py), dotted."""
    out = []
    for top in ("calib_core", "storage", "pipelines", "calib_testing"):
        for init in sorted((ROOT / top).rglob("__init__.py")):
            out.append(".".join(init.parent.relative_to(ROOT).parts))
    return out


def main(extra: list[str]) -> int:
    sys.path.insert(0, str(ROOT))
    from calib_core.procedures import ALL

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "tier.json"
        args = [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-m",
            fast_marker(),
            "-n",
            "2",
            "--dist",
            "loadscope",
        ]
        args += ["-p", "calib_testing.tier_coverage", "--tier-coverage", str(out), *extra]
        ran = subprocess.run(args, cwd=ROOT, check=False)
        solved: dict[str, set[str]] = {}
        modules: set[str] = set()
        for part in Path(tmp).glob("tier.json*"):
            doc = json.loads(part.read_text(encoding="utf-8"))
            for name, tests in doc["solved"].items():
                solved.setdefault(name, set()).update(tests)
            modules.update(doc["modules"])
    missing = []
    print("\nprocedure                 fast tests solving it")
    for proc in ALL:
        n = len({t for t in solved.get(proc.name, ()) if t})
        print(f"{proc.name:25s} {n:5d}")
        missing += [f"procedure {proc.name}"] * (n == 0)
    print("\npackage                   modules loaded")
    for pkg in packages():
        n = sum(m == pkg or m.startswith(pkg + ".") for m in modules)
        print(f"{pkg:25s} {n:5d}")
        missing += [f"package {pkg}"] * (n == 0)
    if missing:
        print("not covered by the fast tier: " + ", ".join(missing), file=sys.stderr)
    if ran.returncode:
        print(f"the fast tier failed (pytest exit {ran.returncode})", file=sys.stderr)
    return 1 if missing or ran.returncode else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
