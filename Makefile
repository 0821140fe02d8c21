# neural-bake: the two commands of the README, and a few helpers.
#   make demo   set up, then run the main job on a bundled sample (fit, coarsen, bake, report)
#   make test   set up, then run the whole test suite
VENV   ?= .venv
PYTHON ?= python3
BIN     = $(VENV)/bin
OUT    ?= demo-out

.PHONY: setup demo test bench-quick clean

$(BIN)/neural-bake: pyproject.toml scripts/setup.sh
	PYTHON=$(PYTHON) bash scripts/setup.sh $(VENV)
	@touch $@

setup: $(BIN)/neural-bake

demo: setup
	$(BIN)/neural-bake demo --out $(OUT)

test: setup
	$(BIN)/python -m pytest -q -n auto

bench-quick: setup
	$(BIN)/neural-bake bench all --quick

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info .pytest_cache
