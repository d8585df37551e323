# Two commands (README): `make run` runs the main job, `make test` runs every test.
# Both create or reuse the local virtual environment .venv and install the project into it.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

$(BIN)/amcp: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(BIN)/amcp

.PHONY: install run test
install: $(BIN)/amcp

run: $(BIN)/amcp
	$(BIN)/amcp certify --out amcp-out

test: $(BIN)/amcp
	$(BIN)/python -m pytest tests properties
