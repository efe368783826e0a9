# YOWO: `make setup` (idempotent, from nothing), `make test`, `make demo`.
VENV ?= $(CURDIR)/.venv
PY := $(VENV)/bin/python

.PHONY: setup test demo clean duplicates
setup:
	bash scripts/setup.sh

test: setup
	$(VENV)/bin/pytest -q

demo: setup
	$(VENV)/bin/yowo demo

clean:
	rm -rf build $(VENV)
