# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
OUT ?= runs

.PHONY: demo test lint bench scenarios clean

$(VENV)/.base: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e .
	touch $@

$(VENV)/.dev: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $(VENV)/.base $@

demo: $(VENV)/.base
	$(VENV)/bin/hqp-tpm run lwr_relaxed --out $(OUT)/lwr_relaxed

test: $(VENV)/.dev
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -q -n 2 --dist loadfile

lint: $(VENV)/.dev
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check . || true

bench: $(VENV)/.dev
	$(PY) benchmarks/run_all.py

scenarios: $(VENV)/.base
	for s in $$($(VENV)/bin/hqp-tpm list --names); do $(VENV)/bin/hqp-tpm run $$s --out $(OUT)/$$s || exit 1; done

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache .ruff_cache
