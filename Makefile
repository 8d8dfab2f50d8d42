# Two commands set up a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test test-slow bench clean

$(STAMP): pyproject.toml
	bash scripts/install.sh
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m voro3d.demo --out out

test: $(STAMP)
	$(PY) -m pytest -q tests

test-slow: $(STAMP)
	$(PY) -m pytest -q tests --slow

clean:
	rm -rf out .pytest_cache
