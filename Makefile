# `make run` sets up .venv on first use and runs the main job; `make test` sets up and runs the tests.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export RL_LOGGING_LEVEL := WARNING

.PHONY: run test test-all lint bench mutate reproduce reproduce-quick clean clean-runs

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[dev,track,mpe]"
	# make the repository root (agents/, envs/, scripts/) importable in this venv only
	$(BIN)/python -c "import site, pathlib; pathlib.Path(site.getsitepackages()[0], 'hrl_torch_repo.pth').write_text('$(CURDIR)\n')"
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/python scripts/taxi_maxq_vs_q.py

test: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow" -n 2

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -n 2

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	$(BIN)/python scripts/bench.py

# every table and figure of docs/reproduction.md from scratch (hours; times in runs/reproduce/times.md)
reproduce: $(STAMP)
	$(BIN)/python scripts/reproduce_all.py

# the same pipeline on one or two seeds and a few thousand steps per part (minutes)
reproduce-quick: $(STAMP)
	$(BIN)/python scripts/reproduce_all.py --quick

# one-line bugs put into the core, one at a time, against the fast suite (not part of CI)
mutate: $(STAMP)
	$(BIN)/python scripts/mutate.py

clean:
	rm -rf $(VENV)

# the run folders (kept by `make clean`)
clean-runs:
	rm -rf runs
