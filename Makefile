# Two commands (README): `make run` runs the main job, `make test` runs the code contracts (`make lint`)
# and every test (pytest's testpaths: tests and properties).
# Both create or reuse the local virtual environment .venv and install the project into it from the
# lock file. `make lock` re-resolves the lock after a change of pyproject.toml; `make upgrade` moves
# it to the newest releases and runs the suite against them.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

# The tested versions of every dependency, with hashes, are pinned in requirements.lock (CPython 3.11,
# Linux x86_64): a fresh clone installs exactly those, then the project itself without dependencies.
$(BIN)/amcp: pyproject.toml requirements.lock
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --require-hashes -r requirements.lock
	$(BIN)/python -m pip install --quiet --no-deps -e .
	touch $(BIN)/amcp

# the documentation site's tools (the docs extra) are pinned in requirements.lock too
$(BIN)/mkdocs: $(BIN)/amcp

LOCK_FLAGS := --extra dev --extra docs --generate-hashes --python-version 3.11 --python-platform x86_64-manylinux_2_34 \
	--custom-compile-command "make lock" --quiet -o requirements.lock

.PHONY: install run test lint lock upgrade docs
install: $(BIN)/amcp

run: $(BIN)/amcp
	$(BIN)/amcp certify --out amcp-out

# the code contracts of docs/architecture.md: pyflakes/isort/pyupgrade and the import layers
lint: $(BIN)/amcp
	$(BIN)/ruff check .
	$(BIN)/lint-imports

# in two worker processes (pytest-xdist; the property suite stays in one of them, so that its tests
# share their closed-loop runs, and its coverage summary is printed by the controller: properties/conftest.py)
test: lint
	$(BIN)/python -m pytest -n 2 --dist loadgroup

# re-resolve requirements.lock after a change of pyproject.toml, keeping every pin that still fits
lock: $(BIN)/amcp
	$(BIN)/uv pip compile pyproject.toml $(LOCK_FLAGS)

# move every pin to the newest release, install them, and run the whole suite against them;
# commit requirements.lock only if the suite is green
upgrade: $(BIN)/amcp
	$(BIN)/uv pip compile pyproject.toml $(LOCK_FLAGS) --upgrade
	$(BIN)/python -m pip install --quiet --require-hashes -r requirements.lock
	$(BIN)/python -m pip install --quiet --no-deps -e .
	$(MAKE) test

# the documentation site, built with warnings as errors into site/
docs: $(BIN)/mkdocs
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site
