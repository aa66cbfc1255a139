"""Public names of a package imported on first use (PEP 562 module ``__getattr__``).

``import pipelines`` must stay cheap (the latency of `calib --help`): the
package's ``__init__`` lists its public API by name and module, and a name's
module is imported only when the name is first used.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable
from typing import Any


def lazy_exports(
    package: str, api: dict[str, list[str]]
) -> tuple[Callable[[str], Any], Callable[[], list[str]], list[str]]:
    """The ``__getattr__``, ``__dir__`` and ``__all__`` of `package` for the names of `api`.

    Parameters
    ----------
    package : the package's ``__name__``.
    api : module -> the public names it defines, as in ``from module import names``.

    Returns
    -------
    (__getattr__, __dir__, __all__) to assign at the package's top level. A name is
    imported once, then kept in the package's namespace; ``__all__`` lists the names
    in the order of `api`.
    """
    module_of = {name: module for module, names in api.items() for name in names}

    def get_attribute(name: str) -> Any:  # noqa: ANN401 - any public object
        module = module_of.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        setattr(sys.modules[package], name, value)
        return value

    def names() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(module_of))

    return get_attribute, names, list(module_of)
