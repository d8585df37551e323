"""Let ``amcp_drake.design(...)``, ``amcp_drake.simulate(...)`` and ``amcp_drake.certify(...)`` work
whether the attribute is the function or its submodule.

Python sets ``amcp_drake.design`` to the *submodule* as soon as ``amcp_drake.design`` is imported
anywhere, which would shadow the documented function of the same name. Each of these submodules
makes itself callable, forwarding to its main function, so both spellings keep working.
"""

from __future__ import annotations

import sys
import types
from typing import Callable


def make_module_callable(module_name: str, function: Callable) -> None:
    """Turn ``sys.modules[module_name]`` into a module whose call runs ``function``."""

    class _CallableModule(types.ModuleType):
        def __call__(self, *args, **kwargs):
            return function(*args, **kwargs)

    sys.modules[module_name].__class__ = _CallableModule
