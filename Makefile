# Entry points; see README.md. `make run` and `make test` set everything up first.
VENV ?= .venv
BIN := $(VENV)/bin
CORES ?= 2

.PHONY: setup run test lint report clean slurm-test

setup:
	bash scripts/setup.sh

run: setup
	$(BIN)/snakemake --cores $(CORES)

lint: setup
	$(BIN)/snakemake --lint
	$(BIN)/snakefmt --check .

# The suite, the report opened in headless Chromium included (installed with apt when missing).
test: lint
	bash scripts/system_packages.sh browser
	$(BIN)/pytest -q

# The smoke workflow on a one-node SLURM cluster started for the test (tests/test_slurm.py), against
# a local run of the same workflow: SLURM, munge and MariaDB come from apt.
slurm-test: setup
	bash scripts/system_packages.sh slurm
	$(BIN)/pytest -q -m slurm -s tests/test_slurm.py

clean:
	rm -rf results .snakemake
