# Single entry point. `make run` and `make test` each create/refresh .venv first.
# Two install stamps: `make run` installs only the runtime dependencies (the main job
# needs no extras); `make test`, `make bench` and `make venv` add the dev set (pytest,
# hypothesis, and every extra: hidapi, pyusb, dask, pyarrow, matplotlib, pymavlink).
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
RUN_STAMP := $(VENV)/.installed-run
DEV_STAMP := $(VENV)/.installed-dev

.PHONY: run test test-fast bench clean venv firmware-tools

venv: $(DEV_STAMP)

$(BIN)/python:
	$(PY) -m venv $(VENV) || python3 -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# The runtime set only. Reinstalled when pyproject.toml changes.
$(RUN_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	@touch $(RUN_STAMP)

# The dev set includes the runtime set, so it refreshes the run stamp too (a later
# `make run` installs nothing).
$(DEV_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	@touch $(DEV_STAMP) $(RUN_STAMP)

# The main job on the embedded default scene: the paper's four transmitters, 10 epochs.
run: $(RUN_STAMP)
	$(BIN)/arva-emulate --port - --frames 10 --speed 0

# The import layers first (pyproject.toml's [tool.importlinter]), then the whole suite in
# two runs: what is not marked pty or timing on 3 xdist workers (a file stays on one worker,
# so its module fixtures are built once; 3 on 2 cores because many tests wait on a child
# process), then the pty and timing tests one at a time on an otherwise quiet machine.
# Both runs always run; the target fails if either failed. Measured idle on this 2-core
# host (docs/architecture.md#tests): 8 min 40 s serial before, 6 min 26 s with 2 workers,
# the first run 269 s -> 232 s with 3; 5 min 28 s on 2026-12-05 after the tests' inputs
# were trimmed to what their assertions need.
SERIAL := pty or timing
test: $(DEV_STAMP) firmware-tools
	$(BIN)/lint-imports
	@status=0; \
	$(BIN)/python -m pytest -q -n 3 --dist loadfile -m "not ($(SERIAL))" tests docs/examples || status=$$?; \
	$(BIN)/python -m pytest -q -p no:xdist -m "$(SERIAL)" tests docs/examples || status=$$?; \
	exit $$status

# The unit layer only: no test marked slow (> 1 s), subprocess or pty (markers in
# pyproject.toml): 1579 tests in 77 s idle on 2026-12-05 (docs/architecture.md#tests);
# `make test` before a merge.
test-fast: $(DEV_STAMP)
	$(BIN)/python -m pytest -q -m "not slow and not subprocess and not pty" tests docs/examples

# Firmware in the loop (tests/emulator/testing/test_firmware_loop.py) needs QEMU and an Arm cross compiler,
# Debian packages: installed here when one is missing and we are root with apt (CI, a
# fresh container); otherwise one line says what to install and those tests skip.
FIRMWARE_PACKAGES := qemu-system-arm gcc-arm-none-eabi libnewlib-arm-none-eabi
firmware-tools:
	@missing=""; for p in $(FIRMWARE_PACKAGES); do \
	  if command -v dpkg-query >/dev/null; then \
	    dpkg-query -W -f='$${Status}' $$p 2>/dev/null | grep -q 'ok installed' || missing="$$missing $$p"; \
	  fi; \
	done; \
	for t in qemu-system-arm arm-none-eabi-gcc; do command -v $$t >/dev/null || missing="$$missing ($$t)"; done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "make: installing $(FIRMWARE_PACKAGES) for the firmware-in-the-loop tests"; \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $(FIRMWARE_PACKAGES)) >/dev/null \
	      || echo "make: could not install $(FIRMWARE_PACKAGES): the firmware-in-the-loop tests will skip"; \
	  else \
	    echo "make: the firmware-in-the-loop tests will skip: as root, apt-get install $(FIRMWARE_PACKAGES)"; \
	  fi; \
	fi

# Benchmarks: each script prints its table and rewrites its section of docs/performance.md.
bench: $(DEV_STAMP)
	@for f in tests/perf/bench_*.py; do echo "== $$f"; $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info
