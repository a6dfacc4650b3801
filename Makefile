# Single entry point. `make run` and `make test` each create/refresh .venv first.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test bench clean venv

venv: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PY) -m venv $(VENV) || python3 -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

# The main job on the embedded default scene: the paper's four transmitters, 10 epochs.
run: $(STAMP)
	$(BIN)/arva-emulate --port - --frames 10 --speed 0

test: $(STAMP)
	$(BIN)/python -m pytest -q tests docs/examples

# Benchmarks: each script prints its table and rewrites its section of docs/performance.md.
bench: $(STAMP)
	@for f in tests/perf/bench_*.py; do echo "== $$f"; $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info
