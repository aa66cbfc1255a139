"""Write docs/api.md from the docstrings of the public Python API.

The API is what the packages' top levels export (``__all__`` of calib_core,
pipelines and storage). tests/test_api.py checks that docs/api.md is what this
script writes, so a changed docstring or signature must be followed by::

    python scripts/api_doc.py          # rewrite docs/api.md
    python scripts/api_doc.py --check  # exit 1 when docs/api.md is out of date
"""

from __future__ import annotations

import importlib
import inspect
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET = ROOT / "docs" / "api.md"
PACKAGES = {
    "pipelines": "Lab files to calibrations, archive, reports and exports (the pipeline's verbs).",
    "calib_core": "The science: data model, procedures, checks (numpy/scipy only, no I/O).",
    "storage": "The archive: open it, ask it questions (answers as dicts and DataFrames).",
}
HEAD = """# Python API

Generated from the docstrings by `scripts/api_doc.py` (tests/test_api.py checks it is
current). Every name below is importable from its package's top level, e.g.
`import pipelines; pipelines.read_run(...)`, and imported on first use. A worked
example is the README's "From Python" section (its code runs in the test suite).
Units are SI throughout (m/s^2, rad/s, deg C for temperatures); parameter names are
the canonical ones of `calib_core.params` (e.g. `gyr.scale.x`).
"""


class _Text(str):
    """An annotation kept as written (``from __future__ import annotations``), unquoted."""

    def __repr__(self) -> str:
        return str(self)


def _signature(obj: object) -> str:
    try:
        sig = inspect.signature(obj)
    except (TypeError, ValueError):
        return ""

    def plain(a: object) -> object:
        return _Text(a) if isinstance(a, str) else a

    def default(d: object) -> object:  # a function's repr holds its address: its name only
        return _Text(d.__name__) if inspect.isfunction(d) else d

    params = [
        p.replace(annotation=plain(p.annotation), default=default(p.default))
        for p in sig.parameters.values()
    ]
    ret = inspect.Signature.empty if inspect.isclass(obj) else plain(sig.return_annotation)
    return str(sig.replace(parameters=params, return_annotation=ret))


def _methods(cls: type) -> list[str]:
    """`name(signature)`: first docstring line, for the public methods a class defines."""
    out = []
    for name, member in vars(cls).items():
        if name.startswith("_") or not callable(getattr(cls, name)):
            continue
        fn = member.__func__ if isinstance(member, classmethod | staticmethod) else member
        doc = (inspect.getdoc(fn) or "").split("\n")[0]
        out.append(f"- `{name}{_signature(fn)}`: {doc}")
    return out


def entry(package: str, name: str) -> list[str]:
    """The markdown of one public name."""
    obj = getattr(importlib.import_module(package), name)
    if isinstance(obj, dict):
        return [f"### `{package}.{name}`", "", "Keys: " + ", ".join(f"`{k}`" for k in obj), ""]
    kind = "class " if inspect.isclass(obj) else ""
    lines = [f"### {kind}`{package}.{name}{_signature(obj)}`", ""]
    if getattr(obj, "__name__", name) != name:  # an old name kept importable
        return lines + [f"Deprecated alias of `{package}.{obj.__name__}`.", ""]
    lines += [f"*Defined in `{obj.__module__}`.*", ""]
    lines += ["```text", inspect.getdoc(obj) or "(no docstring)", "```", ""]
    if inspect.isclass(obj) and (methods := _methods(obj)):
        lines += ["Methods:", "", *methods, ""]
    return lines


def render() -> str:
    """The whole of docs/api.md."""
    lines = [HEAD]
    for package, what in PACKAGES.items():
        module = importlib.import_module(package)
        lines += [f"## `{package}`", "", what, ""]
        for name in module.__all__:
            if not name.startswith("_"):
                lines += entry(package, name)
    return "\n".join(lines).rstrip() + "\n"


def main(argv: list[str]) -> int:
    text = render()
    if "--check" in argv:
        current = TARGET.read_text(encoding="utf-8") if TARGET.exists() else ""
        if current != text:
            print(f"{TARGET} is out of date: run python scripts/api_doc.py", file=sys.stderr)
            return 1
        return 0
    TARGET.write_text(text, encoding="utf-8")
    print(f"wrote {TARGET}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    raise SystemExit(main(sys.argv[1:]))
