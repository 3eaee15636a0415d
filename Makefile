# Entry points; see README.md. `make run` and `make test` set everything up first.
VENV ?= .venv
BIN := $(VENV)/bin
CORES ?= 2

.PHONY: setup run test lint report clean

setup:
	bash scripts/setup.sh

run: setup
	$(BIN)/snakemake --cores $(CORES)

lint: setup
	$(BIN)/snakemake --lint
	$(BIN)/snakefmt --check .

test: lint
	$(BIN)/pytest -q

clean:
	rm -rf results .snakemake
