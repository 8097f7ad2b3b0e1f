# The README's two set-up commands: `make reproduce` and `make test`.
PYTHON ?= python3
VENV   := .venv
STAMP  := $(VENV)/.installed-from-lock

.PHONY: install reproduce test report clean-results

# (Re)create the environment whenever the lock or the package metadata changes.
$(STAMP): environment.lock pyproject.toml
	rm -rf $(VENV)
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install --quiet -r environment.lock
	$(VENV)/bin/pip install --quiet --no-deps -e .
	touch $(STAMP)

install: $(STAMP)

reproduce: install
	$(VENV)/bin/snakemake --cores 2
	$(VENV)/bin/snakemake --report results/report.html

test: install
	$(VENV)/bin/pytest

clean-results:
	rm -rf results
