# One command to set up and start the service, one to run the tests.
PYTHON ?= python3.11
VENV   ?= .venv
BIN    := $(VENV)/bin
HOST   ?= 127.0.0.1
PORT   ?= 8000

.PHONY: run test test-slow lint check docs migrate bench backup clean

$(BIN)/python:
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) (set PYTHON=...)"; exit 1; }
	$(PYTHON) -m venv $(VENV)

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $@

# the pages' browser libraries (Leaflet, Chart.js), pinned by package-lock.json
NODE_MODULES := node_modules/.package-lock.json
$(NODE_MODULES): package.json package-lock.json
	@command -v npm >/dev/null 2>&1 || { echo "need node and npm for the pages (apt install npm)"; exit 1; }
	npm ci --no-audit --no-fund
	touch $@

migrate: $(VENV)/.installed
	$(BIN)/alembic upgrade head

run: migrate $(NODE_MODULES)
	$(BIN)/python -m app.serve --host $(HOST) --port $(PORT)

# the suite on both cores, the slow end-to-end tests (multi-process, soak, fuzz) left to test-slow
test: $(VENV)/.installed $(NODE_MODULES)
	$(BIN)/pytest -n 2 -m "not slow"

test-slow: $(VENV)/.installed
	$(BIN)/pytest -n 2 -m slow

lint: $(VENV)/.installed
	$(BIN)/ruff check app tests bench migrations
	$(BIN)/ruff format --check app tests bench migrations
	$(BIN)/mypy
	$(BIN)/lint-imports

# models and migrations never drift: build the schema on a scratch SQLite and compare
check: $(VENV)/.installed
	$(BIN)/python -m app.platform.configuration --check docs/configuration.md
	rm -rf .check-data && VANTAGE_DATA_DIR=.check-data $(BIN)/alembic upgrade head \
	  && VANTAGE_DATA_DIR=.check-data $(BIN)/alembic check; status=$$?; rm -rf .check-data; exit $$status

# docs/configuration.md, made from the settings
docs: $(VENV)/.installed
	$(BIN)/python -m app.platform.configuration docs/configuration.md

# a consistent copy of the running service's data: make backup DEST=/backups/vantage-$(date +%F)
backup: $(VENV)/.installed
	@test -n "$(DEST)" || { echo "usage: make backup DEST=<new directory>"; exit 1; }
	$(BIN)/python -m app.platform.backup "$(DEST)"

bench: $(VENV)/.installed
	$(BIN)/python bench/ingest.py

clean:
	rm -rf $(VENV) .mypy_cache .ruff_cache .pytest_cache
