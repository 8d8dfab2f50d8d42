# Two commands set up a fresh machine: `make demo` and `make test`.
# `make demo` installs voro3d alone into .venv (no torch); `make test` adds the extras the tests need.
# Each has its stamp, so `make demo` then `make test` upgrades the same venv.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
DEMO_STAMP := $(VENV)/.installed-demo
TEST_STAMP := $(VENV)/.installed-test
# The compiled extensions' sources: an editable install builds them once, so a change to them reinstalls.
EXTENSION_SOURCES := $(wildcard src/*.cpp src/*.h src/clean/*.h)

.PHONY: demo test test-slow docs wheels clean

$(DEMO_STAMP): pyproject.toml setup.py $(EXTENSION_SOURCES)
	bash scripts/install.sh demo
	touch $(DEMO_STAMP)

$(TEST_STAMP): pyproject.toml setup.py $(EXTENSION_SOURCES)
	bash scripts/install.sh test
	touch $(TEST_STAMP) $(DEMO_STAMP)

demo: $(DEMO_STAMP)
	$(PY) -m voro3d.demo --out out
	@echo "next: source .venv/bin/activate, then voro3d --help (README: first ten minutes)"

test: $(TEST_STAMP)
	$(PY) -m pytest -q tests

test-slow: $(TEST_STAMP)
	$(PY) -m pytest -q tests --slow

# benchmarks/README.md from benchmarks/results/*.md (tests/test_docs.py checks it is up to date).
docs:
	$(PY) benchmarks/summary.py

# Binary wheels for CPython 3.10-3.13 into wheelhouse/ (manylinux_2_34_x86_64, GMP and MPFR bundled).
wheels:
	bash scripts/build_wheels.sh

clean:
	rm -rf out .pytest_cache
