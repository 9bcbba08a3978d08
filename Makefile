# The README's two commands: `make demo` (the main job) and `make test`. Each creates .venv on a fresh clone.
# `make venv` installs every extra (training, export, dev, cluster) for the benchmarks and tools.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
PIP    := $(BIN)/python -m pip install --quiet --disable-pip-version-check

.PHONY: demo test venv lint clean convert-env

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(PIP) --upgrade pip

$(VENV)/.stamp-core: pyproject.toml | $(BIN)/python
	$(PIP) -e .
	touch $@

# MAVProxy is a real ground station for the loopback test; its full install would replace opencv-headless and pull
# vtk, so it goes in without its dependencies (pyserial is the only one it needs headless).
$(VENV)/.stamp-test: pyproject.toml | $(BIN)/python
	$(PIP) -e '.[dev,bench,train,cluster]'
	$(PIP) --no-deps mavproxy==1.8.75 pyserial
	touch $@

$(VENV)/.stamp-all: pyproject.toml | $(BIN)/python
	$(PIP) -e '.[dev,bench,train,export,cluster]'
	touch $@

# The TFLite converter (onnx2tf) pins numpy 1.26 and TensorFlow 2.19 (~2.6 GB), so it lives in its own venv that
# `edge-explorer export` calls as a subprocess; the runtime and training environment never import TensorFlow.
# onnx2tf 1.29.24 is the last release for Python 3.11 and pins every one of its dependencies exactly.
CONVERT_VENV := .venv-convert

$(CONVERT_VENV)/.stamp:
	$(PYTHON) -m venv $(CONVERT_VENV)
	$(CONVERT_VENV)/bin/python -m pip install --quiet --disable-pip-version-check --upgrade pip
	$(CONVERT_VENV)/bin/python -m pip install --quiet --disable-pip-version-check onnx2tf==1.29.24
	touch $@

convert-env: $(CONVERT_VENV)/.stamp

demo: $(VENV)/.stamp-core
	$(BIN)/edge-explorer run

test: $(VENV)/.stamp-test
	$(BIN)/python -m pytest -q

venv: $(VENV)/.stamp-all

lint: $(VENV)/.stamp-test
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports

clean:
	rm -rf $(VENV) runs .pytest_cache
