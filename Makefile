.PHONY: setup demo test lint bench docs

setup:
	@bash scripts/setup.sh

demo: setup
	@bash scripts/demo.sh

test: setup
	@bash scripts/test.sh

bench: setup
	@bash -c 'source scripts/env.sh && .venv/bin/python bench/run.py $(BENCH_ARGS)'

docs: setup
	@bash -c 'source scripts/env.sh && .venv/bin/python -m flows.cli_reference docs/cli.md && .venv/bin/mkdocs build --strict'
