# The whole set-up is these targets: `make demo` and `make test`. Also: `make docs` (the site,
# into site/), `make test-py313` (the suite on Python 3.13 in .venv313) and `make package-check`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TESTSTAMP := $(VENV)/.installed-test
DOCSSTAMP := $(VENV)/.installed-docs
# Python 3.13 for `make test-py313`: PY313 if given, else pyenv's newest 3.13, else python3.13.
PY313 ?= $(firstword $(shell ls -d $$HOME/.pyenv/versions/3.13*/bin/python3.13 2>/dev/null \
	| sort -V | tail -n 1) $(shell command -v python3.13 2>/dev/null))
VENV313 := .venv313
STAMP313 := $(VENV313)/.installed-test

.PHONY: demo test test-py313 docs package-check bench elas clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(TESTSTAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $@

$(DOCSSTAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[docs]"
	touch $@

demo: $(STAMP)
	$(BIN)/svains demo --out demo_out --force

# Two pytest-xdist workers (the machine's 2 cores); each test module stays on one worker
# (--dist loadscope), so a module's data-set fixture is built once.
test: $(TESTSTAMP)
	$(BIN)/ruff check src tests bench docs
	$(BIN)/python -m pytest -q -n 2 --dist loadscope

# The same suite on Python 3.13, in its own venv (the lowest supported, 3.11, is `make test`'s
# usual interpreter). Fails when no 3.13 interpreter is found; .ci/run checks first.
$(STAMP313): pyproject.toml
	@test -n "$(PY313)" && test -x "$(PY313)" || { echo "no Python 3.13 (set PY313=...)"; exit 1; }
	test -x $(VENV313)/bin/python || $(PY313) -m venv $(VENV313)
	$(VENV313)/bin/python -m pip install --quiet --upgrade pip
	$(VENV313)/bin/python -m pip install --quiet -e ".[test]"
	touch $@

test-py313: $(STAMP313)
	$(VENV313)/bin/python -m pytest -q -n 2 --dist loadscope

# The documentation site (mkdocs.yml): strict, so a warning (a broken link, a missing page)
# fails it.
docs: $(DOCSSTAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

# Build the sdist and the wheel, install the wheel in a fresh venv and run it.
package-check:
	PY=$(BIN)/python bash .ci/package_check.sh

bench: $(TESTSTAMP)
	$(BIN)/python bench/run_all.py

# Optional: the paper's ELAS dense disparity (pyelas, GPL-3). Its build needs numpy's headers,
# which a plain `pip install pyelas` does not find.
elas: $(STAMP)
	CFLAGS="-I$$($(BIN)/python -c 'import numpy; print(numpy.get_include())')" \
		$(BIN)/python -m pip install --quiet --no-build-isolation pyelas

clean:
	rm -rf $(VENV) $(VENV313) demo_out .pytest_cache site
