# The two commands of the README: `make demo` (the whole stack on the simulated backend)
# and `make test`. Both run the idempotent set-up first.
.PHONY: setup demo test bench

setup:
	bash scripts/setup_env.sh

demo: setup
	scripts/with_env.sh python -m softblock_ros.demo --out out/demo

test: setup
	scripts/with_env.sh python -m pytest -n 2 --dist loadfile -m "not serial" tests
	scripts/with_env.sh python -m pytest -m serial tests

bench: setup
	scripts/with_env.sh bash benchmarks/run_all.sh
