"""Public names of a package imported on first use (PEP 562 module ``__getattr__``).

``import pipelines`` must stay cheap (the `calib --help` latency of issue 19): the
package's ``__init__`` lists its public API by name and module, and a name's
module is imported only when the name is first used.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable
from typing import Any


def lazy_exports(
    package: str, api: dict[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of `package` for the names of `api`.

    Parameters
    ----------
    package : the package's ``__name__``.
    api : public name -> the module that defines it under the same name.

    Returns
    -------
    (__getattr__, __dir__) to assign at the package's top level. A name is
    imported once, then kept in the package's namespace.
    """

    def get_attribute(name: str) -> Any:  # noqa: ANN401 - any public object
        module = api.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        setattr(sys.modules[package], name, value)
        return value

    def names() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(api))

    return get_attribute, names
