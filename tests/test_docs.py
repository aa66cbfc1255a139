"""The docs stay true to the code: every module named in docs/architecture.md, every
citation of docs/methods.md names a section it has, every page in the docs index, no
tracker references.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PACKAGES = ("calib_core", "storage", "pipelines", "calib_testing")
CODE = (*PACKAGES, "tests", "benchmarks", "scripts")


def _tree_blocks() -> dict[str, str]:
    """docs/architecture.md's tree, split by top-level package: {package: its lines}."""
    text = (DOCS / "architecture.md").read_text("utf-8")
    tree = text.split("```", 2)[1]
    blocks: dict[str, list[str]] = {}
    current = None
    for line in tree.splitlines():
        if m := re.match(r"^([a-z_]+)/", line):
            current = m.group(1)
        if current:
            blocks.setdefault(current, []).append(line)
    return {k: "\n".join(v) for k, v in blocks.items()}


def _modules(package: str) -> list[Path]:
    """Every module and subpackage of `package` (its own __init__ and Alembic's scripts
    excepted)."""
    found = []
    for path in sorted((ROOT / package).rglob("*.py")):
        rel = path.relative_to(ROOT / package)
        if "migrations" in rel.parts[:-1] and rel.parts[0] == "migrations":
            continue
        if rel.name == "__init__.py":
            if len(rel.parts) > 1:
                found.append(rel.parent)
            continue
        found.append(rel)
    return found


def missing_modules() -> list[str]:
    blocks = _tree_blocks()
    missing = []
    for package in PACKAGES:
        block = blocks.get(package, "")
        for rel in _modules(package):
            name = rel.stem if rel.suffix else rel.name + "/"
            pattern = rf"(?<![\w.]){re.escape(name)}" + ("" if name.endswith("/") else r"\b")
            if not re.search(pattern, block):
                missing.append(f"{package}/{rel.as_posix()}")
    return missing


def test_architecture_names_every_module() -> None:
    """A new module gets its line in docs/architecture.md's tree (under its package)."""
    missing = missing_modules()
    assert missing == [], "not named in docs/architecture.md: " + ", ".join(missing)


def _methods_sections() -> set[str]:
    text = (DOCS / "methods.md").read_text("utf-8")
    return set(re.findall(r"^#{2,3} (\d+(?:\.\d+)?)[. ]", text, flags=re.M))


CITATION = re.compile(r"methods\.md\)?,? (?:sections? )?(\d+(?:\.\d+)?)")


def test_methods_citations_name_sections_that_exist() -> None:
    sections = _methods_sections()
    assert {"1", "2.1", "2.8", "3.6", "5"} <= sections, sorted(sections)
    bad, cited = [], 0
    for folder in (*CODE, "docs"):
        for path in sorted((ROOT / folder).rglob("*")):
            if path.suffix not in (".py", ".toml", ".md") or not path.is_file():
                continue
            for n, line in enumerate(path.read_text("utf-8").splitlines(), 1):
                for m in CITATION.finditer(line):
                    cited += 1
                    if m.group(1) not in sections:
                        bad.append(f"{path.relative_to(ROOT)} line {n}: section {m.group(1)}")
    assert cited > 30
    assert bad == [], "\n".join(bad)


def test_docs_index_lists_every_page() -> None:
    index = (DOCS / "README.md").read_text("utf-8")
    pages = sorted(p.name for p in DOCS.glob("*.md") if p.name != "README.md")
    assert [p for p in pages if f"({p})" not in index] == []


ISSUE = re.compile(r"\bissues? #?\d+", re.IGNORECASE)


def test_no_references_to_an_issue_tracker() -> None:
    """Issue numbers of a tracker the repository does not hold mean nothing to a reader."""
    paths = [ROOT / "README.md", *DOCS.rglob("*.md")]
    for folder in CODE:
        paths += (ROOT / folder).rglob("*.py")
    bad = [
        f"{p.relative_to(ROOT)} line {n}"
        for p in paths
        for n, line in enumerate(p.read_text("utf-8").splitlines(), 1)
        if ISSUE.search(line)
    ]
    assert bad == []
