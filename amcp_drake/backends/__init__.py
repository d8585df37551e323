"""Backend registry and dispatcher (qpsolvers style).

Backends are detected without importing them (``importlib.util.find_spec``); asking for one that
is unknown or not installed raises :class:`~amcp_drake.model.errors.BackendNotFound` listing what is
installed. ``get_backend(name, **options)`` imports the implementation lazily.
"""

from __future__ import annotations

import importlib
import importlib.util
from typing import Any

from amcp_drake.backends.base import (
    Backend,
    GainResult,
    MPCSolution,
    ProjectionResult,
    SetUpdateResult,
    TubeMPCData,
    TubeMPCSolver,
)
from amcp_drake.model.errors import BackendNotFound

#: backend name -> (module, class name, packages that must be importable)
REGISTRY: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "drake": ("amcp_drake.backends.drake_", "DrakeBackend", ("pydrake",)),
    "cvxpy": ("amcp_reference.backend", "CvxpyBackend", ("cvxpy", "amcp_reference")),
}


def _installed(packages: tuple[str, ...]) -> bool:
    try:
        return all(importlib.util.find_spec(pkg) is not None for pkg in packages)
    except (ImportError, ValueError):
        return False


def available_backends() -> list[str]:
    """Names of the backends whose packages are installed (nothing is imported)."""
    return [name for name, (_, _, pkgs) in REGISTRY.items() if _installed(pkgs)]


def get_backend(name: str | Backend = "drake", **options: Any) -> Backend:
    """Return a backend instance; ``name`` may already be a backend, which is returned as is."""
    if not isinstance(name, str):
        return name
    if name not in REGISTRY:
        raise BackendNotFound(f"unknown backend {name!r}; known backends: {sorted(REGISTRY)}, "
                              f"installed: {available_backends()}")
    module_name, class_name, packages = REGISTRY[name]
    if not _installed(packages):
        raise BackendNotFound(f"backend {name!r} needs the packages {list(packages)}, which are not installed; "
                              f"installed backends: {available_backends()}. Install with `pip install amcp-drake`.")
    module = importlib.import_module(module_name)
    return getattr(module, class_name)(**options)


__all__ = ["Backend", "GainResult", "MPCSolution", "ProjectionResult", "SetUpdateResult", "TubeMPCData",
           "TubeMPCSolver", "REGISTRY", "available_backends", "get_backend"]
