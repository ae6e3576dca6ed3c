.PHONY: setup demo test lint bench docs stack stack-down stack-status

setup:
	@bash scripts/setup.sh

demo: setup
	@bash scripts/demo.sh

test: setup
	@bash scripts/test.sh

bench: setup
	@bash -c 'source scripts/env.sh && .venv/bin/python bench/run.py $(BENCH_ARGS)'

# The services of docker/compose.yaml as native processes (PostgreSQL, Prefect server + worker, S3, Dask).
stack: setup
	@bash scripts/stack.sh up

stack-down:
	@bash scripts/stack.sh down

stack-status:
	@bash scripts/stack.sh status

docs: setup
	@bash -c 'source scripts/env.sh && .venv/bin/python -m flows.cli_reference docs/cli.md && .venv/bin/mkdocs build --strict'
