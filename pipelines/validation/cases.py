"""Where the ground-truth benchmark's simulated cases come from: a provider found at run time.

The cases need the simulator (`calib_core.simulate`), test and benchmark equipment that the
product never imports (tests/test_layers.py). A provider is a callable, case of the set ->
its design with known truth (the protocol of `calib_testing.benchmark_cases.design`),
found either

- by `--cases MODULE[:NAME]` (NAME defaults to `design`), or
- through the entry point group `imu_calib.benchmark_cases`. imu-calib declares one,
  `checkout = "calib_testing.benchmark_cases:design"`: calib_testing ships with a checkout of
  the repository, not with the wheel, so it loads where the checkout's root is importable
  (`PYTHONPATH=.` in the checkout, as the tests and benchmarks run) and, elsewhere, the
  command says what to do. Another distribution may declare its own cases in the group.

Both are loaded the same way (`importlib.metadata.EntryPoint.load`).
"""

from __future__ import annotations

from collections.abc import Callable
from importlib.metadata import EntryPoint, entry_points
from typing import Any

GROUP = "imu_calib.benchmark_cases"
DEFAULT_NAME = "design"
HOW_TO_GET = (
    "the simulated cases ship with a checkout of imu-calib (calib_testing.benchmark_cases), not"
    " with the installed package: run `PYTHONPATH=. calib validate --benchmark` from the root"
    " of a checkout of the installed version's source, give --cases MODULE[:NAME], or install"
    f" a package that declares the entry point group {GROUP}"
)


class NoProviderError(LookupError):
    """No usable provider of the benchmark's cases; the message says what to install or where
    to run."""


def _entry(spec: str) -> EntryPoint:
    """`--cases MODULE[:NAME]` as an entry point of the group (the same loading path)."""
    module, _, name = spec.partition(":")
    if not module.replace(".", "").replace("_", "").isalnum() or (
        name and not name.replace("_", "").isalnum()
    ):
        raise NoProviderError(f"--cases {spec!r}: expected a module path, MODULE[:NAME]")
    return EntryPoint(name="--cases", value=f"{module}:{name or DEFAULT_NAME}", group=GROUP)


def declared() -> list[EntryPoint]:
    """The group's entry points, one per target (an editable install and a wheel of the same
    project may both declare it), in name order."""
    unique = {ep.value: ep for ep in entry_points(group=GROUP)}
    return sorted(unique.values(), key=lambda ep: (ep.name, ep.value))


def find_provider(spec: str | None = None) -> tuple[str, Callable[[Any], Any]]:
    """The cases provider: ("name = target", callable).

    Parameters
    ----------
    spec : `--cases` MODULE[:NAME]; None: the entry point group's one provider.

    Raises NoProviderError naming what was looked for, why it did not load and what to do.
    """
    if spec:
        candidates = [_entry(spec)]
    else:
        candidates = declared()
        if not candidates:
            raise NoProviderError(f"no benchmark cases provider ({GROUP}): {HOW_TO_GET}")
        if len(candidates) > 1:
            names = ", ".join(f"{ep.name} = {ep.value}" for ep in candidates)
            raise NoProviderError(f"several benchmark cases providers ({names}): pick one, --cases")
    (ep,) = candidates
    try:
        provider = ep.load()
    except (ImportError, AttributeError) as exc:
        raise NoProviderError(
            f"the benchmark cases provider {ep.value} cannot be loaded ({exc}): {HOW_TO_GET}"
        ) from None
    if not callable(provider):
        raise NoProviderError(f"the benchmark cases provider {ep.value} is not callable")
    return f"{ep.name} = {ep.value}", provider
