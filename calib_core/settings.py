"""Typed settings: `Setting` (name, kind, unit, default, bounds or choices, meaning), a
`Settings` declaration, the typed values it parses a table into (`Settings.parse`: a frozen
dataclass, one attribute per setting) and the `SettingError` that names the refused key.

The one way settings are declared and checked: a procedure's, the preprocessing tables', a
tolerance profile's sections, a manifest's and the lab's and mission profiles' tables
(`typed`), the JSON files read as written (`checked`: an approvers file's lines, a
checkpoint, the benchmark set); `refusal` is the one message of a refused file."""

from __future__ import annotations

import copy
import dataclasses
import difflib
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import date, datetime
from typing import Any

# What a solver's door takes: its procedure's typed values, or a mapping `Settings.parse` reads.
SettingsIn = Any
# The value kinds a setting may take, as TOML writes them, and their Python types.
TYPES = {"number": float, "integer": int, "bool": bool, "text": str, "table": dict, "list": list,
         "date": date, "datetime": datetime}  # fmt: skip


class SettingError(ValueError):
    """A key refused: ``key`` is its dotted name under `root` (``run.settings`` of a
    manifest; "" for a tolerance profile's top level), ``limits[2].unit`` for an entry of
    an array of tables."""

    def __init__(self, key: str, problem: str, root: str = "run.settings") -> None:
        self.key = key
        self.problem = problem
        self.root = root
        # "run.settings.k: expected a positive number, got -1"; "run.settings.x must be ..."
        where = f"{root}.{key}" if root else key
        super().__init__(f"{where}{'' if problem.startswith('must') else ':'} {problem}")


def _is_kind(value: Any, kind: str) -> bool:
    if kind == "number":
        return isinstance(value, int | float) and not isinstance(value, bool)
    if kind == "integer":
        return isinstance(value, int) and not isinstance(value, bool)
    if kind == "date":  # a calendar day, not a date and time
        return isinstance(value, date) and not isinstance(value, datetime)
    return isinstance(value, TYPES[kind])


@dataclass(frozen=True)
class Setting:
    """One setting of a procedure.

    name : the key in ``[run.settings]``.
    kind : "number", "integer", "bool", "text", "table", "list", "date" or "datetime"; a
        tuple for a setting
        that takes one of several kinds (e.g. "text" or "table").
    unit : the value's unit as the manifest writes it ("s", "deg/s", "deg", "1", "").
    default : the value when absent; None: absent means "not given" (inferred or unused).
    meaning : one line for the documentation.
    low, high : inclusive bounds of a number (None: unbounded); low_open excludes `low`,
        high_open `high`.
    choices : the allowed texts of a "text" setting.
    length : the number of items of a "list" setting.
    """

    name: str
    kind: str | tuple[str, ...]
    unit: str
    default: Any
    meaning: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()
    length: int | None = None

    def annotation(self) -> Any:
        """The Python type of its values (``float | None``, ``str | dict``)."""
        kinds = [TYPES[k] for k in self.kinds] + [type(None)] * (self.default is None)
        out = kinds[0]
        for t in kinds[1:]:
            out = out | t
        return out

    @property
    def kinds(self) -> tuple[str, ...]:
        return self.kind if isinstance(self.kind, tuple) else (self.kind,)

    def allowed(self) -> str:
        """What the setting accepts, as a refusal and the documentation print it."""
        parts = []
        for kind in self.kinds:
            if kind == "text" and self.choices:
                parts.append("one of " + ", ".join(repr(c) for c in self.choices))
            elif kind in ("number", "integer"):
                parts.append(self._number(kind))
            elif kind == "list" and self.length is not None:
                parts.append(f"a list of {self.length} finite numbers")
            else:
                words = {"bool": "true or false", "table": "a table", "date": "a date (YYYY-MM-DD)",
                         "datetime": "a date and time (ISO 8601)"}  # fmt: skip
                parts.append(words.get(kind, kind))
        return " or ".join(parts)

    def _number(self, kind: str) -> str:
        noun = "a number" if kind == "number" else "a whole number"
        lo, hi = self.low is not None, self.high is not None
        if lo and hi:
            left, right = "(["[not self.low_open], ")]"[not self.high_open]
            return f"{noun} in {left}{self.low:g}, {self.high:g}{right}"
        if lo and self.low == 0.0:
            return noun.replace("a ", "a positive " if self.low_open else "a non-negative ")
        if lo:
            return f"{noun} {'>' if self.low_open else '>='} {self.low:g}"
        return f"{noun} <= {self.high:g}" if hi else noun

    def check(self, value: Any) -> None:
        """Raise SettingError naming the key, the value and what is allowed."""
        if value is None and self.default is None:
            return
        kind = next((k for k in self.kinds if _is_kind(value, k)), None)
        refused = kind is None or (
            (kind in ("number", "integer") and not self._inside(float(value)))
            or (
                kind == "list"
                and self.length is not None
                and (
                    len(value) != self.length
                    or not all(_is_kind(v, "number") and math.isfinite(v) for v in value)
                )
            )
        )
        if kind == "text" and self.choices and value not in self.choices:
            raise SettingError(self.name, f"must be {self.allowed()}, got {value!r}")
        if refused:
            raise SettingError(self.name, f"expected {self.allowed()}, got {value!r}")

    def _inside(self, x: float) -> bool:
        if not math.isfinite(x):
            return False
        if self.low is not None and (x < self.low or (self.low_open and x == self.low)):
            return False
        return self.high is None or x < self.high or (x == self.high and not self.high_open)


class Settings:
    """A table's settings: the typed declaration its values are validated against.

    `type` is the frozen dataclass `parse` returns (named `name`), one attribute per
    setting, typed by its kind (None where its default is None), defaulting to its default.
    """

    def __init__(
        self, *settings: Setting, name: str = "Values", noun: str = "setting", base: type = object
    ) -> None:
        self.items: dict[str, Setting] = {s.name: s for s in settings}
        self.noun = noun  # what its keys are called in a refusal ("field", "condition")
        self.type = dataclasses.make_dataclass(  # `base`: the values' methods
            name,
            [(s.name, s.annotation(), _default(s.default)) for s in settings],
            bases=(base,),
            frozen=True,
            namespace={"as_dict": dataclasses.asdict},
        )

    def __iter__(self):
        return iter(self.items.values())

    def __contains__(self, name: object) -> bool:
        return name in self.items

    def defaults(self) -> dict[str, Any]:
        """name -> default of every setting."""
        return {s.name: s.default for s in self}

    def validate(self, given: Mapping[str, Any], table: str, root: str = "run.settings") -> None:
        """Check a whole table: unknown keys (with the closest valid one), types, bounds.

        `table` is its name under `root` ("outliers" under run.settings; "recall" of a
        tolerance profile, root ""), or "" for `root` itself.
        """
        where = f"{table}." if table else ""
        header = ".".join(p for p in (root, table) if p)
        of = f" of [{header}]" if header else ""
        for key, value in given.items():
            if key not in self.items:
                hint = did_you_mean(key, list(self.items))
                raise SettingError(f"{where}{key}", f"unknown {self.noun}{of}{hint}", root)
            try:
                self.items[key].check(value)
            except SettingError as exc:
                raise SettingError(f"{where}{key}", exc.problem, root) from None

    def parse(self, given: Mapping[str, Any] | None | Any) -> Any:
        """The typed values (`type`) of `given`: values already typed pass as they are; a
        mapping is checked key by key (`merged`), defaults filled in, other keys left out."""
        if isinstance(given, self.type):
            return given
        return self.type(**copy.deepcopy(self.merged(given)))

    def merged(self, given: Mapping[str, Any] | None) -> dict[str, Any]:
        """The declared settings with defaults filled in, each checked; other keys left out."""
        out = self.defaults()
        for key, value in (given or {}).items():
            if key in self.items:
                self.items[key].check(value)
                out[key] = value
        return out


def typed(table: Settings, given: Any, root: str, required: tuple[str, ...] = ()) -> Any:
    """`given` (typed values of `table`, or a mapping of them) typed as the archive keeps
    them: texts stripped of surrounding blanks, whole numbers of a "number" setting as
    floats; SettingError naming ``root.key`` for a value that is not a table, an unknown
    key, a refused value or a `required` key missing or empty. The one reading of a
    file's table: a manifest's, a mission profile's, a lab profile's."""
    if isinstance(given, table.type):
        return given
    if not isinstance(given, Mapping):
        raise SettingError(root, f"expected a table, got {given!r}", "")
    number = {s.name for s in table if "number" in s.kinds}
    given = {
        k: v.strip() if isinstance(v, str) else float(v) if k in number and type(v) is int else v
        for k, v in given.items()
    }
    return table.parse(checked(table, given, root, required))


def checked(
    table: Settings,
    given: Any,
    root: str,
    required: tuple[str, ...] = (),
    others: bool = False,
) -> Mapping[str, Any]:
    """`given` as written, checked against `table`: SettingError naming ``root.key`` for a
    value that is not a table (JSON: an object), an unknown key (unless `others`: keys
    not declared are then left to their readers), a refused value or a `required` key
    missing or empty. The check `typed` makes; JSON files' readers call it on values they
    keep as written (an approvers file's names, a checkpoint)."""
    if not isinstance(given, Mapping):
        raise SettingError(
            root or "(top level)", f"expected a table (an object), got {given!r}", ""
        )
    table.validate({k: v for k, v in given.items() if k in table or not others}, "", root)
    for key in required:
        if given.get(key) in (None, ""):
            raise SettingError(key, "required field is missing", root)
    return given


# The dotted key a refusal starts with: "limits[3].unit: ...", "recall.method must".
_KEY = re.compile(r"^([A-Za-z_]\w*(?:\[\d+\]|\.[A-Za-z_]\w*)*)")


def line_of(text: str, problem: str) -> str:
    """The " line N" of the key a `problem` starts with ("limits[3].unit: ...") in the
    TOML `text` of a file (a tolerance or lab profile), or "" when not found."""
    m = _KEY.match(problem)
    if m is None:
        return ""
    path = key_path(m[1])
    # A key inside an inline table ("gyr_std = { value, unit }"): the line of the table.
    lines = (key_line(text, path[:n]) for n in range(len(path), 0, -1))
    line = next((n for n in lines if n is not None), None)
    return "" if line is None else f" line {line}"


def refusal(
    what: str, path: Any, text: str | None, exc: Exception, line: int | None = None
) -> ValueError:
    """A settings file refused: ``<what> <path> line N: <key>: <problem>``. N is `line`
    when given (a file of one JSON object a line), else the line of the key `exc` (a
    SettingError) names in the TOML `text`; left out when not known: a JSON document
    (`text` None) is named by its dotted key path only."""
    at = f" line {line}" if line is not None else line_of(text, str(exc)) if text else ""
    return ValueError(f"{what} {path}{at}: {exc}")


def _default(value: Any) -> Any:
    return dataclasses.field(default_factory=lambda: copy.deepcopy(value))


def did_you_mean(key: str, known: list[str]) -> str:
    near = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
    if near:
        return f"; did you mean {near[0]}?"
    return f"; expected one of {', '.join(sorted(known))}"


def key_path(dotted: str) -> tuple[str | int, ...]:
    """``"limits[3].unit"`` -> ``("limits", 3, "unit")``."""
    return tuple(int(p) if p.isdigit() else p for p in re.split(r"[.\[\]]+", dotted) if p)


def key_line(text: str, path: tuple) -> int | None:
    """1-based line of the key at dotted `path` (``("segments", 2, "end_s")``) in the TOML
    `text` of a manifest or profile: the key assigned under its table's header (``[a.b]``,
    the n-th ``[[a]]``, a ``[a.b]`` of the latest ``[[a]]``), or a dotted key under a
    shorter header; None when it is spelt otherwise (inline tables)."""
    keys = [p for p in path if not isinstance(p, int)]
    counts: dict[str, int] = {}
    header: tuple = ()
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.split("#", 1)[0].strip()
        if stripped.startswith("["):
            names = stripped.strip("[]").strip().split(".")
            if stripped.startswith("[["):
                counts[".".join(names)] = counts.get(".".join(names), -1) + 1
            header = ()
            for i in range(len(names)):  # each array of tables at its latest entry
                at = counts.get(".".join(names[: i + 1]))
                header += (names[i],) if at is None else (names[i], at)
            continue
        key = stripped.split("=", 1)[0].strip().strip("\"'")
        if "=" not in stripped or not key:
            continue
        full = (*header, *key.replace('"', "").split("."))
        named = [p for p in full if not isinstance(p, int)]
        if named == keys and [p for p in full if isinstance(p, int)] == [
            p for p in path if isinstance(p, int)
        ]:
            return number
    return None
