# The two entry points of the README: each does the whole set-up on a fresh
# machine (virtualenv, project with dev extras, FMUs) and then runs.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test fmus bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# Reinstall when the dependency list changes.
$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

fmus: $(STAMP)
	$(BIN)/v2i build-fmus

# The project's main job: the Intersection Movement Assist case study with and without the RSU's
# perception service, in lockstep, each with its verdict, then both runs side by side in one report.
DEMO := runs/demo-$(shell date +%Y%m%d-%H%M%S)
demo: fmus
	$(BIN)/v2i run scenarios/ima_case_study.toml --out $(DEMO)/ima_case_study
	$(BIN)/v2i run scenarios/ima_no_cps.toml --out $(DEMO)/ima_no_cps
	$(BIN)/v2i report $(DEMO)/ima_case_study $(DEMO)/ima_no_cps

test: fmus
	$(BIN)/python -m pytest -q

# The perception benchmark's held-out dataset (README, RECIPE.md): rendered once, about 3 minutes.
HELDOUT := data/heldout/annotations.json
$(HELDOUT): | fmus
	$(BIN)/v2i dataset --scenario scenarios/ima_world.toml --out data/heldout --frames 400 --seed 1001 \
	    --variant heldout --backgrounds --jobs 2

bench: fmus $(HELDOUT)
	$(BIN)/python benchmarks/master_overhead.py
	$(BIN)/python benchmarks/j2735_codec.py
	$(BIN)/python benchmarks/serial_link.py
	$(BIN)/python benchmarks/channel.py
	$(BIN)/python benchmarks/world.py
	$(BIN)/python benchmarks/bridges.py
	$(BIN)/python benchmarks/perception.py
	$(BIN)/python benchmarks/sdsm_vs_bsm.py --e2e
	$(BIN)/python benchmarks/request_to_green.py

clean:
	rm -rf build runs
