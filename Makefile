# Two commands (README): `make run` runs the main job, `make test` runs the code contracts (`make lint`)
# and every test (pytest's testpaths: tests and properties).
# Both create or reuse the local virtual environment .venv and install the project into it.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

$(BIN)/amcp: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(BIN)/amcp

# the documentation site: MkDocs with warnings as errors, written to site/
$(BIN)/mkdocs: $(BIN)/amcp
	$(BIN)/python -m pip install --quiet -e '.[dev,docs]'
	touch $(BIN)/mkdocs

.PHONY: install run test lint docs
install: $(BIN)/amcp

run: $(BIN)/amcp
	$(BIN)/amcp certify --out amcp-out

# the code contracts of docs/architecture.md: pyflakes/isort/pyupgrade and the import layers
lint: $(BIN)/amcp
	$(BIN)/ruff check .
	$(BIN)/lint-imports

test: lint
	$(BIN)/python -m pytest

docs: $(BIN)/mkdocs
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site
