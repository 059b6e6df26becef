# hostd: two commands on a fresh machine: `make run` and `make test`.
# The interpreter the .venv is made from: the distribution's own Python when it is
# 3.11 or newer and has its venv module (Debian builds it with profile-guided and
# link-time optimisation: it starts in 7 ms against 15 for a plain source build,
# runs pure Python 1.3-1.5x faster, and is the one a printer's computer runs the
# service on), else the first python3 on PATH. `make PYTHON=...` picks another.
PYTHON ?= $(or $(shell for p in /usr/bin/python3 python3; do \
	  if $$p -c 'import sys, ensurepip; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; \
	  then echo $$p; break; fi; done),python3)
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: run test test-fast lint bench clean system-deps

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	# bytecode written once, as an installed package has it (PYTHONDONTWRITEBYTECODE
	# would otherwise leave every `hostd slice` compiling the project's modules anew)
	$(BIN)/python -m compileall -q hostd slicer drivers tui >/dev/null
	touch $(STAMP)

# Debian packages the test suite uses (real MQTT brokers: mosquitto, a nats-server
# cluster); installed only when missing and when running as root, otherwise the
# tests fall back or skip.
system-deps:
	@if ! command -v mosquitto >/dev/null 2>&1 && [ ! -x /usr/sbin/mosquitto ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing mosquitto (MQTT broker for the tests)"; \
	    apt-get update -qq >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mosquitto >/dev/null || true; \
	  fi; \
	fi
	@if ! command -v nats-server >/dev/null 2>&1 && [ ! -x /usr/sbin/nats-server ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing nats-server (clustered MQTT broker for the tests)"; \
	    apt-get update -qq >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq nats-server >/dev/null || true; \
	  fi; \
	fi
	@if ! command -v mosquitto >/dev/null 2>&1 && [ ! -x /usr/sbin/mosquitto ]; then \
	  echo "mosquitto unavailable: installing the Python broker amqtt instead"; \
	  $(BIN)/pip install --quiet amqtt || true; \
	fi

run: $(STAMP)
	$(BIN)/python -m hostd.app.demo

# The suite waits on daemons and ptys more than on the CPU: it runs in two workers
# (a test file stays on one worker, so module fixtures are built once), and mypy
# beside it; mypy's report follows the suite's, and either failing fails the target
test: $(STAMP) system-deps
	$(BIN)/ruff check .
	$(BIN)/lint-imports
	@report=$$(mktemp); $(BIN)/mypy > $$report 2>&1 & checker=$$!; \
	$(BIN)/python -m pytest -q -n 2 --dist loadfile; suite=$$?; \
	wait $$checker; typed=$$?; cat $$report; rm -f $$report; \
	[ $$suite -eq 0 ] && [ $$typed -eq 0 ]

# The inner loop: the unit layer only (tests/unit: no pty, no subprocess, no broker,
# no daemon, no SQLite), in under a minute; `make test` runs every layer, unit first
test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 -m "not slow" tests/unit

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports
	$(BIN)/mypy

bench: $(STAMP)
	$(BIN)/python bench/slice_vs_peers.py
	$(BIN)/python bench/stream_throughput.py
	$(BIN)/python bench/drop_to_extrusion.py
	$(BIN)/python bench/lead_over_printer.py
	$(BIN)/python bench/eta.py --plot docs/eta_error.png

clean:
	rm -rf $(VENV) var jobs .pytest_cache
