# aobake: `make bake` sets up .venv and bakes data/ into out/; `make test` runs the suite.
# Batch: `make -j2 batch IN=dir OUT=dir` bakes every mesh in IN into OUT, only what changed
# (`aobake batch` does the same on a Dask cluster: docs/batch.md).

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
AOBAKE := $(VENV)/bin/aobake
STAMP  := $(VENV)/.installed
BAKE_FLAGS ?= --quiet

IN  ?= data
OUT ?= out
MESH_EXT := ply obj stl off glb gltf usd usda usdc
INPUTS   := $(foreach e,$(MESH_EXT),$(wildcard $(IN)/*.$(e)))
STEMS    := $(basename $(notdir $(INPUTS)))
OUT_PLY  := $(STEMS:%=$(OUT)/%.ply)
OUT_USD  := $(STEMS:%=$(OUT)/%.usda)
# the lit colour of the bundled Cornell box, previewed (when IN holds it)
OUT_PNG  := $(if $(wildcard $(IN)/cornell_box.usda),$(OUT)/cornell_box.png)

.PHONY: help venv bake batch test bench bench-deps bench-embree bench-bunnell bench-field bench-batch bench-process bench-light report lint coverage clean

help: ## Show this help
	@awk 'BEGIN {FS = ":.*?## "} /^[a-zA-Z_-]+:.*?## / {printf "  %-14s %s\n", $$1, $$2}' $(MAKEFILE_LIST)

venv: $(STAMP) ## Create .venv and install aobake with its test extras

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test,plot]'
	@touch $@

# Compiles the kernels once (aobake warm-up, quick when cached), then says what it baked
# ("baked data/x.ply -> ..."), or that nothing needed baking.
bake: $(STAMP) ## Compile the kernels once (aobake warm-up), then bake every mesh in data/ into out/ (PLY and USD; out/cornell_box.png: its lit colour)
	@$(AOBAKE) warm-up
	@if $(MAKE) -q --no-print-directory batch IN=$(IN) OUT=$(OUT); then \
	  echo "$(OUT)/ is up to date ($(words $(STEMS)) meshes)"; \
	else $(MAKE) --no-print-directory batch IN=$(IN) OUT=$(OUT); fi

batch: $(STAMP) $(OUT_PLY) $(OUT_USD) $(OUT_PNG) ## Bake IN=dir into OUT=dir (parallel with -j, only what changed)

# One bake per mesh writes both files (grouped targets, GNU make >= 4.3); one rule per
# input suffix, so data/x.obj and data/x.ply map to out/x.* (the first found wins).
define BAKE_RULE
$$(OUT)/%.ply $$(OUT)/%.usda &: $$(IN)/%.$(1) $$(STAMP) | $$(OUT)
	@$$(AOBAKE) bake $$< -o $$(OUT)/$$*.ply -o $$(OUT)/$$*.usda $$(BAKE_FLAGS)
	@echo "baked $$< -> $$(OUT)/$$*.ply, $$(OUT)/$$*.usda"
endef
$(foreach e,$(MESH_EXT),$(eval $(call BAKE_RULE,$(e))))

$(OUT):
	@mkdir -p $@

# PLY has no up axis; the bundled procedural scenes are +Z up (data/README.md).
out/sphere_on_ground.ply out/sphere_on_ground.usda out/box_stack.ply out/box_stack.usda: BAKE_FLAGS += --up Z
# The Cornell box is lit: its vertex colours are the lit colour, one stop brighter.
$(OUT)/cornell_box.ply $(OUT)/cornell_box.usda: BAKE_FLAGS += --color --exposure 1

$(OUT)/cornell_box.png: $(OUT)/cornell_box.ply
	@$(AOBAKE) preview $< --show color --view front -o $@
	@echo "previewed $< -> $@"

test: $(STAMP) ## Run the test suite
	$(PY) -m pytest -q --durations=20

bench: bench-embree bench-bunnell bench-field bench-batch bench-process bench-light ## All benchmarks (ratios measured in one run; ~50 min on 2 cores)

bench-deps: $(STAMP)
	$(PY) -m pip install --quiet -e '.[bench]' || echo "libigl not installable: peer rows skipped"

bench-embree: bench-deps ## Embree reference: closed forms, adaptivity, vs bare embreex and libigl
	$(PY) bench/accuracy_embree.py
	$(PY) bench/adaptive_embree.py
	$(PY) bench/bench_embree.py

bench-bunnell: $(STAMP) ## Bunnell disks: error and time per pass against Embree
	$(PY) bench/bench_bunnell.py

bench-field: $(STAMP) ## AO fields: fit time, size, error, evaluation throughput
	$(PY) bench/bench_field.py

bench-batch: $(STAMP) ## aobake batch: 200 meshes against make -j2 batch, up-to-date rerun, --split 2 on 4M vertices
	$(PY) bench/bench_batch.py

bench-process: $(STAMP) ## Whole process (wall, peak RSS, bytes/vertex, stage shares) on 721k and ~3.7M vertices, vs bare embreex
	$(PY) bench/bench_process.py --big

bench-light: $(STAMP) ## Light transport: shadow/bounce ray rate vs AO rays, RMSE on the box (RectLight, emissive quad), error coverage
	$(PY) bench/bench_light.py

report: $(STAMP) ## Sweep accuracy vs time on the bundled meshes into report/ (tables + pareto.png; the lit box: irradiance too)
# the procedural scenes carry their own floor: no field rows (a field is for one rigid object)
	@mkdir -p report; for f in $(wildcard data/*.ply) data/cornell_box.usda; do \
	  stem=$$(basename $$f); stem=$${stem%.*}; \
	  echo "## $$stem"; \
	  opts="--up Y"; case $$stem in sphere_on_ground|box_stack) opts="--up Z --no-fields";; cornell_box) opts="--no-fields";; esac; \
	  $(AOBAKE) sweep $$f -o report/$$stem $$opts --quiet > report/$$stem.md.tmp && mv report/$$stem.md.tmp report/$$stem.md || exit 1; \
	  cat report/$$stem.md; \
	done

lint: $(STAMP) ## ruff check (installs ruff into .venv)
	$(PY) -m pip install --quiet ruff
	$(PY) -m ruff check aobake tests bench

# Kernels run as plain Python here (slow), so only the suites that exercise the sampling
# and ray kernels on small meshes are run; extend COVERAGE_TESTS as time allows.
COVERAGE_TESTS ?= tests/test_sampling.py tests/test_determinism.py
coverage: $(STAMP) ## Coverage with NUMBA_DISABLE_JIT=1 so kernel bodies count (a subset: COVERAGE_TESTS)
	$(PY) -m pip install --quiet coverage
	NUMBA_DISABLE_JIT=1 $(PY) -m coverage run --source aobake -m pytest -q $(COVERAGE_TESTS)
	$(PY) -m coverage report --include 'aobake/kernels/*'

clean: ## Remove outputs and caches (keeps .venv)
	rm -rf out .pytest_cache .hypothesis
	find . -name __pycache__ -prune -exec rm -rf {} +
