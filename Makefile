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

# Blender as a Python module (bpy 4.2 LTS, built for Python 3.11), in a venv of
# its own: `make blender-check` opens the exported .glb files in Blender's glTF
# importer. Not part of `make test` (a ~350 MB download).
BLENDER_VENV ?= .venv-blender
BLENDER_STAMP := $(BLENDER_VENV)/.installed-stamp
BPY_VERSION ?= 4.2.23
GLB ?= $(DEMO_DIR)

ICT_TAKE ?= bench/out/ict-take

REPORT ?= $(DEMO_DIR)/results

.PHONY: test demo bench env bytecode clean blender-check blender-check-ict report-check

# `.[test]` includes the optional `speech` extra (Praat, PocketSphinx and its model, PyAV),
# so that the tests run the real speech tools, and the `speed` extra (numba), so that they
# run the compiled marker placement and solver; the core install needs none of them.
env: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

# The package's modules byte-compiled, those whose cache is older than their source: pip
# compiles an installed wheel but not an editable install's sources, and Python does not
# cache them itself where PYTHONDONTWRITEBYTECODE is set (as container images often set
# it), so every process compiled them at its start: 0.2 s of every mocap2mesh command.
bytecode: $(STAMP)
	$(PY) -m compileall -q mocap basis fit

test: bytecode
	$(PY) -m pytest -q

demo: bytecode
	$(VENV)/bin/mocap2mesh demo -o $(DEMO_DIR)

bench: bytecode
	@set -e; for script in bench/bench_*.py; do echo "== $$script"; \
	    env -u OPENBLAS_NUM_THREADS $(PY) $$script; done

$(BLENDER_STAMP):
	$(PYTHON) -m venv $(BLENDER_VENV)
	$(BLENDER_VENV)/bin/python -m pip install --quiet 'bpy==$(BPY_VERSION)'
	touch $(BLENDER_STAMP)

# Opens every .glb under GLB (default: the demo's outputs, made if absent) in
# Blender and compares the mesh it evaluates at every frame with ours.
blender-check: bytecode $(BLENDER_STAMP)
	@if [ -z "$$(find $(GLB) -name '*.glb' 2>/dev/null | head -n 1)" ]; then \
	    $(VENV)/bin/mocap2mesh demo -o $(DEMO_DIR); fi
	$(BLENDER_VENV)/bin/python bench/blender_check.py $(GLB)

# The same on a 9,409-vertex ICT take (needs ../shared/data), made by bench/ict_take.py.
blender-check-ict: bytecode $(BLENDER_STAMP)
	$(PY) bench/ict_take.py $(ICT_TAKE)
	$(BLENDER_VENV)/bin/python bench/blender_check.py $(ICT_TAKE)/results

# Opens every report under REPORT (default: the demo's, made if absent) in a real
# headless Chromium (Debian's package, installed here): no console error, every
# <video> has a duration and plays; writes a full-page screenshot beside each.
report-check: bytecode
	@command -v chromium > /dev/null || { apt-get update -qq && \
	    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium > /dev/null; }
	@if [ -z "$$(find $(REPORT) -name '*.html' 2>/dev/null | head -n 1)" ]; then \
	    $(VENV)/bin/mocap2mesh demo -o $(DEMO_DIR); fi
	$(PY) bench/report_check.py $(REPORT)

clean:
	rm -rf $(VENV) $(BLENDER_VENV) $(DEMO_DIR) bench/out .pytest_cache
