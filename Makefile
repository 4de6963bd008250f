# Quick start: `make demo` and `make test`, each on a fresh machine.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
OUT    ?= out/tse2
MINUTES ?= 60

.PHONY: venv demo test test-slow claims bench bench-imu bench-smoother bench-soak bench-campaign bench-scaling lint docs clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/liemef reproduce tse2 --out $(OUT)

# JAX's persistent compilation cache and liemef's C kernels, shared by the test processes (xdist workers, CLI
# subprocesses, Dask workers): a program compiled in one is loaded, not compiled again, in another, and in the
# next run; kept in the checkout, so that the tests leave the user's ~/.cache/liemef alone.
JAX_CACHE := JAX_COMPILATION_CACHE_DIR=$(CURDIR)/.cache/jax LIEMEF_CACHE_DIR=$(CURDIR)/.cache/liemef

# Where `make test`'s time goes (cold caches): compiling, not computing (tools/suite_profile.py times every
# XLA compile and C compiler call by test file; a cold run under load, December 2026: XLA compiles 43 % of the
# tests' time, 9055 programs, 8057 of them under 0.2 s each). Besides the filters' own programs, each
# eager jnp operation on a new shape is a small XLA compile of its own, about 40 ms of CPU each on an AMD Zen 4:
# test_cli, test_montecarlo and test_campaign (run alone) make 559 XLA compiles, at least 318 of them such
# single operations (metrics/_stats.py, the key indexing of studies/experiments/_montecarlo.py, the groups);
# collecting the tests compiles about 75 more in each xdist worker (~2.6 s of CPU). `liemef run`'s report
# arrays are jitted (1eb9b01). Measured and kept: the tests' processes compile every XLA program without
# XLA's expensive optimisations (tests/fast_compile.py: no fast-math, every tolerance holds, the last bits move,
# so the pinned figures are computed in a process with XLA's defaults), a cold run from 1050 s to 678 s
# (LIEMEF_TEST_XLA_DEFAULTS=1 runs the suite with XLA's defaults, as users' runs are compiled); each kernel's
# -O2 build only once its quick build has served 2 s of calls (262 -O2 builds in a cold run before, the bulk of
# the C compiler's time; test_engine.py alone 198 s -> 149 s); and --dist loadfile (a file's tests in one
# worker, the heaviest files first: tests/conftest.py) instead of worksteal, which split a file's tests and
# compiled their programs in both workers: a cold run from 1064 s to 838-903 s. Measured and left out:
# jax_persistent_cache_min_compile_time_secs=0 (the two workers compile the same small programs at the same
# time: no gain cold). `make test-slow` runs only the `@pytest.mark.slow` tests: the full-size studies and the
# heaviest variants of fast tests.
# --max-worker-restart=0: under --dist loadfile pytest-xdist does not replace a crashed worker cleanly (it then
# waits forever, as a CI run did until its limit after a worker's SIGABRT), so a crash ends the run at once,
# with the test it happened in named.
test: $(STAMP)
	$(JAX_CACHE) $(PY) -m pytest -n 2 --dist loadfile --no-loadscope-reorder --max-worker-restart=0 -q --durations=30

test-slow: $(STAMP)
	$(JAX_CACHE) $(PY) -m pytest -q -m slow

# Every table of numbers in README.md and docs/ that a command makes, made again into out/claims and compared
# (docs/claims.toml lists the commands; tools/claims.py says how they are compared). Over an hour on 2 cores;
# CLAIMS="NAME ..." runs some, CLAIMS_ARGS=--fast only those of a minute, --coverage counts what is checked.
# The real-data tables need LIEMEF_REALDATA.
claims: $(STAMP)
	$(JAX_CACHE) $(PY) tools/claims.py --out out/claims $(CLAIMS_ARGS) $(CLAIMS)

bench: $(STAMP)
	$(PY) benchmarks/bench_tse2.py
	$(PY) benchmarks/bench_batch.py
	$(PY) benchmarks/bench_real_logs.py
	$(PY) benchmarks/bench_first_call.py
	$(PY) benchmarks/bench_quick_build.py
	$(PY) benchmarks/bench_side.py

# compare broad's bounded-velocity filters per sample beside VQF's updateBatch on one whole BROAD trial, in one
# process on one core (issue 36's ratio; needs the real recordings, LIEMEF_REALDATA; about a minute).
bench-imu: $(STAMP)
	$(PY) benchmarks/bench_imu.py

# The whole-log smoother's cost per sample at 1k-16k samples and the fixed-lag smoother's per step, beside the
# filter's, on ukfm's planar localization (a few minutes).
bench-smoother: $(STAMP)
	$(PY) benchmarks/bench_smoother.py

# One hour of 1 kHz TSE(2) data (3.6 M filter steps), chunk by chunk; MINUTES=2 for a smoke test.
# The hour takes 5-11 min on one core of a shared 2-core machine (load average 4-8), 30-40 s of it compiling;
# MINUTES=2 takes 1-2 min.
bench-soak: $(STAMP)
	$(PY) benchmarks/bench_soak.py --minutes $(MINUTES)

# Campaign throughput with 1 and 2 local Dask workers, overhead per task, and the 10^6-seed estimate (1-3 min).
bench-campaign: $(STAMP)
	$(PY) benchmarks/bench_campaign.py

# Cost per step against the state dimension n (R^n, n = 3..24, and the papers' systems) for run, batched and
# the exported C: JSON and scaling.png into OUT (default out/scaling), about 10 min, most of it compiling;
# SCALING_ARGS=--quick for a smoke test (1-2 min). docs/performance.md explains the figures.
bench-scaling: OUT = out/scaling
bench-scaling: $(STAMP)
	$(PY) benchmarks/bench_scaling.py --out $(OUT) $(SCALING_ARGS)

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests benchmarks tools examples

docs: $(STAMP)
	$(VENV)/bin/mkdocs build --strict -d site

clean:
	rm -rf $(VENV) out site .pytest_cache .cache
