# gsa_jax -- everything runs inside .venv (created on first use).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install demo test bench clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[test]"
	touch $(STAMP)

install: $(STAMP)

## demo: a short real training run (mixture of 4 linear controllers on inverted_double_pendulum, ~1-2 min)
demo: $(STAMP)
	$(BIN)/python -m gsa_jax.train --env inverted_double_pendulum --policy mixture --clusters 4 --steps 150000 --out runs/demo

## test: the pytest suite (~ a few minutes on 2 cores)
test: $(STAMP)
	$(BIN)/python -m pytest -q tests -m "not benchmark"

## bench: the long measurements (tests marked benchmark)
bench: $(STAMP)
	$(BIN)/python -m pytest -q tests -m benchmark -s

clean:
	rm -rf $(VENV) runs .pytest_cache
