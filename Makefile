PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo study test bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/roadcollab reproduce --out results/demo

study: $(STAMP)
	$(BIN)/roadcollab sweep --out results/sweep --workers 2
	$(BIN)/roadcollab attack --out results/attack
	$(BIN)/roadcollab anomalies --out results/anomalies

test: $(STAMP)
	$(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/roadcollab bench

clean:
	rm -rf $(VENV) results
