# The README's two set-up commands: `make reproduce` and `make test`.
PYTHON ?= python3
VENV   := .venv
STAMP  := $(VENV)/.installed-from-lock

.PHONY: install browser reproduce test report clean-results reproduce-ci cluster-local mlflow-ui mlflow-server mlflow-screenshot

# MLflow UI / server: local by default (127.0.0.1); MLFLOW_HOST=0.0.0.0 shares it (see docs/workflow.md)
MLFLOW_HOST  ?= 127.0.0.1
MLFLOW_PORT  ?= 5000
MLFLOW_STORE ?= sqlite:///results/mlflow.db

# (Re)create the environment whenever the lock or the package metadata changes.  --no-compile: Python
# compiles a module when it is first imported; compiling every file of torch, scipy and mlflow up front
# took a third of the install (62 -> 44 s from a warm pip cache).  That compiled code is kept only where
# Python may write it: a shell with PYTHONDONTWRITEBYTECODE set (some CI images and sandboxes set it) would make
# every process compile pandas, scipy, numba, torch ... from source again, twice the CPU of each `qr` start
# (`qr filter --help`: 4.3 -> 2.0 s of CPU, measured under load) and of each of the workflow's and the tests' hundreds of processes.
unexport PYTHONDONTWRITEBYTECODE

$(STAMP): environment.lock pyproject.toml
	rm -rf $(VENV)
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install --quiet --no-compile -r environment.lock
	$(VENV)/bin/pip install --quiet --no-compile --no-deps -e .
	touch $(STAMP)

install: $(STAMP)

# Headless Chromium for the overview's browser test (tests/workflow/test_overview.py): Debian's package, installed
# only where it is missing (needs root, as CI has).
browser:
	@command -v chromium >/dev/null || (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null)

reproduce: install
	$(VENV)/bin/snakemake --cores 2
	$(VENV)/bin/snakemake --report results/report.html

test: install browser
	$(VENV)/bin/pytest -n 2 --dist loadgroup

clean-results:
	rm -rf results

# The whole workflow on the reduced config (2 flights per set, small sweeps; what the tests run).
reproduce-ci: install
	$(VENV)/bin/snakemake --cores 2 --configfile conf/workflow_ci.yaml

# The README's Results section (between its results markers) from results/ (qr.report.readme); the config that
# wrote results/ is read from them, or given: make readme-results CONFIG=ci|full|<your name>.
.PHONY: readme-results
readme-results: install
	$(VENV)/bin/python -m qr.report.readme $(if $(CONFIG),--config-name '$(CONFIG)')

# The same through Snakemake's generic-cluster executor with local stand-ins for submit/status/cancel.
cluster-local: install
	$(VENV)/bin/snakemake --profile profiles/local-cluster --configfile conf/workflow_ci.yaml

# Browse the runs: one experiment per stage (qr-ingest, qr-filter, qr-learn, ...).  Ctrl-C stops it.
mlflow-ui: install
	@echo "Open http://$(MLFLOW_HOST):$(MLFLOW_PORT)/#/experiments?workflowType=machine_learning (each experiment's description links its runs with their results)"
	MLFLOW_SERVER_ENABLE_JOB_EXECUTION=false $(VENV)/bin/mlflow ui --backend-store-uri $(MLFLOW_STORE) \
	    --host $(MLFLOW_HOST) --port $(MLFLOW_PORT) --workers 1

# A tracking server for shared tracking (jobs on other machines: MLFLOW_TRACKING_URI=http://<host>:$(MLFLOW_PORT)).
# Artifacts are uploaded through the server into results/mlartifacts.
mlflow-server: install
	MLFLOW_SERVER_ENABLE_JOB_EXECUTION=false $(VENV)/bin/mlflow server --backend-store-uri $(MLFLOW_STORE) \
	    --artifacts-destination results/mlartifacts --host $(MLFLOW_HOST) --port $(MLFLOW_PORT) --workers 1

# docs/mlflow_ui.png: headless Chromium against `make mlflow-ui` (needs Debian's chromium).
mlflow-screenshot: install
	$(VENV)/bin/python docs/mlflow_screenshot.py docs/mlflow_ui.png

