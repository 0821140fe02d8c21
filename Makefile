# neural-bake: the two commands of the README, and a few helpers.
#   make demo   set up, then run the main job on a bundled sample (fit, coarsen, bake, report)
#   make test   set up, then run the whole test suite
#   make setup-blender   Blender (bpy) in its own venv, .cache/blender-venv, for the Cycles row of `bench bake`
#                        (a download of several hundred MB; no other target needs it)
VENV   ?= .venv
PYTHON ?= python3
BIN     = $(VENV)/bin
OUT    ?= demo-out

.PHONY: setup setup-blender demo test bench-quick clean

$(BIN)/neural-bake: pyproject.toml scripts/setup.sh
	PYTHON=$(PYTHON) bash scripts/setup.sh $(VENV)
	@touch $@

setup: $(BIN)/neural-bake

setup-blender:
	bash scripts/setup-blender.sh

demo: setup
	$(BIN)/neural-bake demo --out $(OUT)

test: setup
	$(BIN)/python -m pytest -q -n auto

bench-quick: setup
	$(BIN)/neural-bake bench all --quick

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info .pytest_cache
