# The two commands of the README: `make demo` (the whole stack on the simulated backend)
# and `make test`. Both run the idempotent set-up first. `make test-fast` is the quick gate: the fast tier.
.PHONY: setup demo demo-reconfigure test test-fast bench

PYTEST := scripts/with_env.sh python -m pytest

setup:
	bash scripts/setup_env.sh

demo: setup
	scripts/with_env.sh python -m softblock_ros.demo --out out/demo

# The second demo: the strawberry gripper reconfigured for the asymmetric object, one wrong swap caught.
demo-reconfigure: setup
	scripts/with_env.sh python -m softblock_ros.demo_reconfigure --out out/reconfigure

# The tiers (pyproject.toml's markers), cheapest first, so that a broken basic stops the run early.
# Integration modules stay on one worker each (--dist loadfile): they share module-wide nodes and ROS domains.
# Their tests mostly wait for processes and messages, so four workers share the two cores (191 s -> 129 s).
# The stack tests run last, on two workers (tests/conftest.py's --dist-stack): the two-host module starts on one,
# the demo on the other, and the other one-host modules follow in the order that keeps both about equally long.
# They mostly wait for ramps, so they overlap.
test: setup
	$(PYTEST) -n 2 -m fast tests
	$(PYTEST) -n 4 --dist loadfile -m integration tests
	$(PYTEST) -n 2 --dist-stack -m stack tests

test-fast: setup
	$(PYTEST) -n 2 -m fast tests

bench: setup
	scripts/with_env.sh bash benchmarks/run_all.sh
