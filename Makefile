# Two commands on a fresh machine: `make demo` (the library and its `app` extra) and `make test`.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
OUT ?= runs

.PHONY: demo test test-pin-lowest lint docs bench bench-peers bench-venvs scenarios clean

$(VENV)/.base: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[app]'
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

# The documentation site (docs/ and the docstrings; mkdocs.yml): warnings are errors. Open site/index.html.
docs: $(VENV)/.dev
	$(VENV)/bin/mkdocs build --strict --site-dir site

lint: $(VENV)/.dev
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check . || true

bench: $(VENV)/.dev
	$(PY) -m pip install -q "pyinstrument>=4.6"  # the profiling part of the benchmark only
	$(PY) benchmarks/run_all.py

# The lowest pinocchio pyproject.toml claims, in its own venv: pin 3.4.0 (its wheels need these cmeel pins)
# with the example-robot-data 4.4 loaders (the 5.0 loaders need pinocchio.WITH_COLLISION, which pin 3.4 lacks)
# and the 5.0 robot files (MuJoCo refuses two inertias of the 4.4 files' romeo and talos: A + B < C).
PIN_LOWEST ?= 3.4.0
VENV_PIN_LOWEST ?= .venv-pin-lowest

$(VENV_PIN_LOWEST)/.dev: pyproject.toml
	$(PYTHON) -m venv $(VENV_PIN_LOWEST)
	$(VENV_PIN_LOWEST)/bin/python -m pip install -q --upgrade pip
	$(VENV_PIN_LOWEST)/bin/python -m pip install -q -e '.[dev]' 'pin==$(PIN_LOWEST)' 'cmeel-urdfdom==4.0.1' 'cmeel-tinyxml2<11' \
		'example-robot-data==4.4.0' 'example-robot-data-loaders==4.4.0'
	$(VENV_PIN_LOWEST)/bin/python -m pip install -q --no-deps 'example-robot-data==5.0.0'  # the loaders pin 4.4.0
	touch $@

test-pin-lowest: $(VENV_PIN_LOWEST)/.dev
	$(VENV_PIN_LOWEST)/bin/python -c "import pinocchio; assert pinocchio.__version__ == '$(PIN_LOWEST)', pinocchio.__version__"
	$(VENV_PIN_LOWEST)/bin/python -m pytest -q -n 2 --dist loadfile

scenarios: $(VENV)/.base
	$(PY) -m pip install -q -e '.[sim]'  # the *_mujoco scenarios run on MuJoCo
	for s in $$($(VENV)/bin/hqp-tpm list --names); do $(VENV)/bin/hqp-tpm run $$s --out $(OUT)/$$s || exit 1; done

clean:
	rm -rf $(VENV) $(VENV_PIN_LOWEST) $(OUT) site .pytest_cache .ruff_cache

# Side-by-side benchmark against pink, PlaCo and TSID (benchmarks/peers/). The peers pin different
# pinocchio versions, so each gets its own virtual environment (git-ignored), all from PyPI, each
# with this checkout installed (editable) beside them.
BENCH_VENVS ?= .bench-venvs
PEERS_ARGS ?=

$(BENCH_VENVS)/pin4/.ok: pyproject.toml
	rm -rf $(BENCH_VENVS)/pin4 && $(PYTHON) -m venv $(BENCH_VENVS)/pin4
	$(BENCH_VENVS)/pin4/bin/python -m pip install -q --upgrade pip
	$(BENCH_VENVS)/pin4/bin/python -m pip install -q -e . 'pin>=4,<5' 'pin-pink==4.4.0' daqp
	touch $@

$(BENCH_VENVS)/pin38/.ok: pyproject.toml
	rm -rf $(BENCH_VENVS)/pin38 && $(PYTHON) -m venv $(BENCH_VENVS)/pin38
	$(BENCH_VENVS)/pin38/bin/python -m pip install -q --upgrade pip
	$(BENCH_VENVS)/pin38/bin/python -m pip install -q -e . 'pin==3.8.0' 'placo==0.10.2' 'pin-pink==4.4.0' daqp
	touch $@

$(BENCH_VENVS)/pin34/.ok: pyproject.toml
	rm -rf $(BENCH_VENVS)/pin34 && $(PYTHON) -m venv $(BENCH_VENVS)/pin34
	$(BENCH_VENVS)/pin34/bin/python -m pip install -q --upgrade pip
	$(BENCH_VENVS)/pin34/bin/python -m pip install -q -e . 'pin==3.4.0' 'tsid==1.7.1' 'cmeel-urdfdom==4.0.1' 'cmeel-tinyxml2<11'
	touch $@

bench-venvs: $(BENCH_VENVS)/pin4/.ok $(BENCH_VENVS)/pin38/.ok $(BENCH_VENVS)/pin34/.ok

bench-peers: bench-venvs
	$(BENCH_VENVS)/pin4/bin/python benchmarks/peers/run.py --env pin4 --scenarios $(PEERS_ARGS)
	$(BENCH_VENVS)/pin38/bin/python benchmarks/peers/run.py --env pin38 $(PEERS_ARGS)
	$(BENCH_VENVS)/pin34/bin/python benchmarks/peers/run.py --env pin34 $(PEERS_ARGS)
	$(BENCH_VENVS)/pin4/bin/python benchmarks/peers/report.py
