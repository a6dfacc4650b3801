# Single entry point. `make run` and `make test` each create/refresh .venv first.
# Two install stamps: `make run` installs only the runtime dependencies (the main job
# needs no extras); `make test`, `make bench` and `make venv` add the dev set (pytest,
# hypothesis, and the extras the tests exercise: dask, pyarrow, matplotlib, pymavlink).
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
RUN_STAMP := $(VENV)/.installed-run
DEV_STAMP := $(VENV)/.installed-dev

.PHONY: run test bench clean venv

venv: $(DEV_STAMP)

$(BIN)/python:
	$(PY) -m venv $(VENV) || python3 -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# The optional C kernel of the model (setup.py): a changed source is rebuilt by reinstalling.
BUILD_INPUTS := pyproject.toml setup.py emulator/receiver/model_kernel.c

# The runtime set only. Rebuilt when pyproject.toml, setup.py or the C kernel changes.
$(RUN_STAMP): $(BUILD_INPUTS) | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	@touch $(RUN_STAMP)

# The dev set includes the runtime set, so it refreshes the run stamp too (a later
# `make run` installs nothing).
$(DEV_STAMP): $(BUILD_INPUTS) | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	@touch $(DEV_STAMP) $(RUN_STAMP)

# The main job on the embedded default scene: the paper's four transmitters, 10 epochs.
run: $(RUN_STAMP)
	$(BIN)/arva-emulate --port - --frames 10 --speed 0

test: $(DEV_STAMP)
	$(BIN)/python -m pytest -q tests docs/examples

# Benchmarks: each script prints its table and rewrites its section of docs/performance.md.
bench: $(DEV_STAMP)
	@for f in tests/perf/bench_*.py; do echo "== $$f"; $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info emulator/receiver/model_kernel*.so
