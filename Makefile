# Every target builds its own environment from a fresh checkout.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
DEMO_DIR ?= demo-output

# The chain runs many small dense solves (eigh of 135x135, 53x53 systems); on a
# 2-core machine multi-threaded OpenBLAS made them up to 9x slower than one
# thread (measured on the PCA gap fill), so tests and the demo use one thread.
# Benchmarks keep the default and say what they use.
export OPENBLAS_NUM_THREADS ?= 1

.PHONY: test demo bench env clean

env: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q

demo: $(STAMP)
	$(VENV)/bin/mocap2mesh demo -o $(DEMO_DIR)

bench: $(STAMP)
	@set -e; for script in bench/bench_*.py; do echo "== $$script"; \
	    env -u OPENBLAS_NUM_THREADS $(PY) $$script; done

clean:
	rm -rf $(VENV) $(DEMO_DIR) bench/out .pytest_cache
