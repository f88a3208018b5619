# runout: set-up, demo, tests, benchmarks.
# torch is pinned so that a CPU machine takes the CPU wheel instead of several GB of CUDA packages;
# override with `make setup TORCH=torch==2.13.0+cu126 ...` on a GPU machine.
PYTHON ?= python3
TORCH  ?= torch==2.13.0
VENV   := .venv
BIN    := $(VENV)/bin

.PHONY: setup demo test bench clean

setup: $(VENV)/.installed

# constraints.txt: the exact versions the tests last passed with (see its header).
$(VENV)/.installed: pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q "$(TORCH)"
	$(BIN)/pip install -q -c constraints.txt -e ".[test]"
	touch $@

demo: setup
	$(BIN)/runout demo --out out/demo

test: setup
	$(BIN)/python -m pytest -q

bench: setup
	$(BIN)/python bench/mpm.py --frames 20 --batches 1,8 --backends torch,warp
	$(BIN)/python bench/mpm.py --frames 20 --batches 1,8 --backends torch --compile --float32
	$(BIN)/python bench/gns.py --repeats 2

clean:
	rm -rf $(VENV) out .pytest_cache
