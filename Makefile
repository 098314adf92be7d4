# The whole set-up is these targets: `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TESTSTAMP := $(VENV)/.installed-test

.PHONY: demo test lint bench elas clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(TESTSTAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $@

demo: $(STAMP)
	$(BIN)/svains demo --out demo_out --force

# Two pytest-xdist workers (the machine's 2 cores); each test module stays on one worker
# (--dist loadscope), so a module's data-set fixture is built once.
test: $(TESTSTAMP)
	$(BIN)/ruff check src tests bench
	$(BIN)/python -m pytest -q -n 2 --dist loadscope

bench: $(TESTSTAMP)
	$(BIN)/python bench/run_all.py

# Optional: the paper's ELAS dense disparity (pyelas, GPL-3). Its build needs numpy's headers,
# which a plain `pip install pyelas` does not find.
elas: $(STAMP)
	CFLAGS="-I$$($(BIN)/python -c 'import numpy; print(numpy.get_include())')" \
		$(BIN)/python -m pip install --quiet --no-build-isolation pyelas

clean:
	rm -rf $(VENV) demo_out .pytest_cache
