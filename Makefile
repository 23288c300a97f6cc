# Two commands do all the set-up on a fresh machine:
#   make demo   -- simulate a recording, estimate motion, write pictures to demo_out/
#   make test   -- run the test suite
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench docs clean

$(STAMP): pyproject.toml
	@command -v $(PY) >/dev/null 2>&1 || { echo "need $(PY) (Python >= 3.11)"; exit 1; }
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[test]"
	# the package's bytecode, written once: where PYTHONDONTWRITEBYTECODE is set, every
	# command would otherwise compile evmotion's modules again (0.3-0.4 s a command)
	$(BIN)/python -m compileall -q src
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/python -m evmotion.demo --out demo_out

test: $(STAMP)
	$(BIN)/ruff check src tests benchmarks examples docs/conf.py conftest.py
	$(BIN)/python -m pytest -n 2 -q

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks examples docs/conf.py conftest.py

bench: $(STAMP)
	$(BIN)/python benchmarks/run.py

# the documentation site, offline: the gallery scripts draw the pictures the pages show,
# then Sphinx (warnings are errors) writes docs/_build/html/index.html
DOCS_STAMP := $(VENV)/.installed-docs
$(DOCS_STAMP): $(STAMP)
	$(BIN)/python -m pip install -q -e ".[docs]"
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	rm -rf docs/_gallery
	for f in examples/*.py; do MPLBACKEND=Agg $(BIN)/python $$f docs/_gallery || exit 1; done
	$(BIN)/python -m sphinx -W --keep-going -q -b html docs docs/_build/html
	@echo "docs: open docs/_build/html/index.html"

clean:
	rm -rf $(VENV) demo_out .pytest_cache docs/_build docs/_gallery examples_out
