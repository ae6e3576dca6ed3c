.PHONY: setup demo test lint bench

setup:
	@bash scripts/setup.sh

demo: setup
	@bash scripts/demo.sh

test: setup
	@bash scripts/test.sh

bench: setup
	@bash -c 'source scripts/env.sh && .venv/bin/python bench/run.py $(BENCH_ARGS)'
