"""Every docstring example of the package runs: the modules whose source holds a ``>>>`` example are
collected and run as doctests (the package's own docstring, the Python API, among them)."""

from __future__ import annotations

import doctest
import importlib
import pkgutil
from pathlib import Path

import pytest

import amcp_drake


def _modules_with_examples() -> list[str]:
    names = ["amcp_drake"]
    for info in pkgutil.walk_packages(amcp_drake.__path__, "amcp_drake."):
        spec = importlib.util.find_spec(info.name)
        if spec is not None and spec.origin and spec.origin.endswith(".py") and ">>>" in Path(spec.origin).read_text():
            names.append(info.name)
    return names


MODULES = _modules_with_examples()


def test_the_package_docstring_has_an_example():
    assert ">>> cert = amcp.certify(traj)" in amcp_drake.__doc__


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name):
    module = importlib.import_module(name)
    tests = [t for t in doctest.DocTestFinder().find(module) if t.examples]
    if name == "amcp_drake":
        assert tests, "the package docstring's example was not collected"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in tests:
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} docstring examples of {name} failed"
