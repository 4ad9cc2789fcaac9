# Two commands on a fresh machine: `make demo` and `make test`. Both create .venv (Python 3.11) if it is
# missing and install mocapflow into it with the CPU build of PyTorch (requirements-cpu.txt).
# `make demo` shows the three systems in turn (DeepMoCap, UUO, the suit; a few minutes each on two cores), each in
# mocapflow-demo-all/<system>/ with its report page; one system: `make demo SYSTEM=uuo` (deepmocap, uuo or suit).

PYTHON ?= python3.11
SYSTEM ?= all
VENV ?= .venv
BIN := $(VENV)/bin
TORCH_CPU_INDEX := https://download.pytorch.org/whl/cpu
INSTALL := -r requirements-cpu.txt -e ".[test,monocular]"

.PHONY: demo test install

demo: install
	$(BIN)/mocapflow demo --system $(SYSTEM)

test: install
	$(BIN)/python -m pytest -q -n auto --durations=40

install: $(VENV)/.installed

# Reinstalled when the dependencies change. Where pip cannot find torch==2.13.0+cpu, the same install
# again with PyTorch's CPU wheel index.
$(VENV)/.installed: pyproject.toml requirements-cpu.txt
	@test -x $(BIN)/python || { command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found; install Python 3.11 or run make PYTHON=/path/to/python3.11" >&2; exit 1; }; $(PYTHON) -m venv $(VENV); }
	$(BIN)/python -m pip install -q $(INSTALL) || \
	  { echo "retrying with PyTorch's CPU index ($(TORCH_CPU_INDEX))" >&2; \
	    $(BIN)/python -m pip install -q --extra-index-url $(TORCH_CPU_INDEX) $(INSTALL); }
	touch $@
