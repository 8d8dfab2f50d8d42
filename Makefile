# Two commands set up a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test test-slow wheels clean

$(STAMP): pyproject.toml
	bash scripts/install.sh
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m voro3d.demo --out out

test: $(STAMP)
	$(PY) -m pytest -q tests

test-slow: $(STAMP)
	$(PY) -m pytest -q tests --slow

# Binary wheels for CPython 3.10-3.13 into wheelhouse/ (manylinux_2_34_x86_64, GMP and MPFR bundled).
wheels:
	bash scripts/build_wheels.sh

clean:
	rm -rf out .pytest_cache
