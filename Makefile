# Front door. `make demo` and `make test` create .venv on first use (every extra, at the
# versions constraints.txt pins).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint format reference bench clean

$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[train,dev,slam,ray,ros,viz]"
	touch $(STAMP)

demo: $(STAMP)  ## the main job on the embedded default (no download)
	$(BIN)/slimseg demo

test: $(STAMP) lint  ## lint, then the whole test suite (slow tests included)
	$(BIN)/python -m pytest -q

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
