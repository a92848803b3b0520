# The two quick-start commands; both create the virtualenv on first use.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-quick firmware clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	$(BIN)/labrig-warm   # compile the simulator now, not in the first command
	touch $(STAMP)

demo: $(STAMP)          ## the main job on the simulated rig -> demo_out/report.html
	$(BIN)/labrig demo -o demo_out

test: $(STAMP)          ## the whole test suite on both cores (firmware and browser tests need the AVR toolchain and Chromium)
	$(BIN)/python -m pytest -q -n 2 --dist load --durations=40 -m "not firmware"
	# the emulated board runs in real time: its tests get the machine to themselves (beside
	# the other worker's fits it dropped samples in 3 of 7 runs on 2 cores)
	$(BIN)/python -m pytest -q -m firmware

# the end-to-end loop files (diagnose, propose, plants, real rigs, sheets, report) are left
# to `make test`; what is left runs in about two minutes on 2 cores
QUICK_SKIP := $(foreach f,diagnose propose plants real_rigs recordings exercises report,--ignore=tests/test_$(f).py)

test-quick: $(STAMP)    ## about two minutes: no slow, firmware, browser or end-to-end loop tests
	$(BIN)/python -m pytest -q -n 2 --dist load -m "not slow and not firmware and not browser" $(QUICK_SKIP)

firmware:               ## build both boards and run the C unit tests
	$(MAKE) -C firmware all test

clean:
	rm -rf demo_out .pytest_cache
