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

.PHONY: install run test lint
install: $(BIN)/amcp

run: $(BIN)/amcp
	$(BIN)/amcp certify --out amcp-out

# the code contracts of docs/architecture.md: pyflakes/isort/pyupgrade and the import layers
lint: $(BIN)/amcp
	$(BIN)/ruff check .
	$(BIN)/lint-imports

test: lint
	$(BIN)/python -m pytest
