# The two quick-start commands; both create the virtualenv on first use.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test firmware clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	$(BIN)/python -m labrig.model.warm   # compile the simulator now, not in the first command
	touch $(STAMP)

demo: $(STAMP)          ## the main job on the simulated rig -> demo_out/report.html
	$(BIN)/labrig demo -o demo_out

test: $(STAMP)          ## the whole test suite (firmware tests need the AVR toolchain)
	$(BIN)/python -m pytest -q

firmware:               ## build both boards and run the C unit tests
	$(MAKE) -C firmware all test

clean:
	rm -rf demo_out .pytest_cache
