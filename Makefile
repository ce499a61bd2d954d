# Front door. `make demo` and `make test` create .venv on first use (every extra, at the
# versions constraints.txt pins).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: help demo test test-fast lint format reference bench clean

$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[train,dev,slam,calibrate,ray,ros,viz,openvino]"
	touch $(STAMP)

help:  ## this list: each target with its comment
	@awk -F ':.*## ' '/^[a-z-]+:.*## /{printf "  %-10s %s\n", $$1, $$2}' $(MAKEFILE_LIST)

demo: $(STAMP)  ## the main job on the embedded default (no download)
	$(BIN)/slimseg demo

# `make test` is what CI runs: everything, the 25 slowest tests listed at the end, in two
# pytest-xdist workers (a serial run kept one of CI's two cores idle half the time).
# `make test-fast` is the inner loop: lint, then every test not marked `slow` (pytest.mark.slow:
# training, export, Ray, notebooks, ...); before a merge run `make test`.
test: $(STAMP) lint  ## lint, then the whole test suite (slow tests included), 25 slowest listed
	$(BIN)/python -m pytest -q -n 2 --durations=25

test-fast: $(STAMP) lint  ## lint, then the tests not marked slow (-m "not slow"): the inner loop
	$(BIN)/python -m pytest -q -n 2 -m "not slow" --durations=10

lint: $(STAMP)  ## ruff, and the layer order of docs/architecture.md (import-linter)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports --no-cache

format: $(STAMP)
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

bench: $(STAMP)  ## every benchmark, one after the other (ratios are measured within each run)
	$(BIN)/slimseg bench --model yolov8s-seg yolov8s-seg-gs-rep --imgsz 640
	$(BIN)/python benchmarks/int8_latency.py --model yolov8n-seg yolov8s-seg yolov8s-seg-gs-rep --imgsz 320 640
	$(BIN)/python benchmarks/train_throughput.py
	$(BIN)/python benchmarks/masking_logic.py
	$(BIN)/python benchmarks/restoration.py
	$(BIN)/python benchmarks/slam_engines.py
	$(BIN)/python benchmarks/mask_path.py
	$(BIN)/python benchmarks/mask_quality.py

reference: $(STAMP)  ## regenerate tests/reference/complexity.json; review the diff like code
	$(BIN)/python tools/gen_complexity_reference.py

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache

.PHONY: fuzz
fuzz: $(STAMP)  ## the long mutation-fuzzing run over recordings of every profile (docs/bags.md)
	nice -n 15 $(BIN)/python tests/bag_fuzz.py --cases 100000 --seed 1000
