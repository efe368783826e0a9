# YOWO: `make setup` (idempotent, from nothing), `make test`, `make demo`.
VENV ?= $(CURDIR)/.venv
PY := $(VENV)/bin/python

.PHONY: setup test demo clean duplicates format
setup:
	bash scripts/setup.sh

test: setup
	$(VENV)/bin/pytest -q

demo: setup
	$(VENV)/bin/yowo demo

format: setup
	$(VENV)/bin/ruff format src tests scripts
	$(VENV)/bin/ruff check --fix src tests scripts

clean:
	rm -rf build $(VENV)
