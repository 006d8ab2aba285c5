# advocc_ros: `make demo` runs the main job, `make test` the tests. Both create .venv on demand.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.advocc-installed
MSGS   := $(shell find msg_defs -type f | sort)
OUT    ?= out/demo
PYTEST_ARGS ?=

.PHONY: install demo test perf clean

install: $(STAMP)

$(PY):
	@$(PYTHON) -c 'import sys; assert sys.version_info[:2] == (3, 11), \
	  "advocc_ros needs Python 3.11 (the ROS 2 Jazzy wheels are cp311); set PYTHON=..."'
	$(PYTHON) -m venv $(VENV)

# One stamp for the whole environment: pinned wheels, OMPL fix-up, interfaces, our package.
$(STAMP): $(PY) setup.py setup.cfg package.xml tools/install.sh $(MSGS)
	tools/install.sh $(VENV)
	touch $@

demo: $(STAMP)
	$(VENV)/bin/advocc demo --out $(OUT)

test: $(STAMP)
	$(PY) -m pytest $(PYTEST_ARGS)

perf: $(STAMP)
	$(VENV)/bin/advocc perf heatmap --json
	$(VENV)/bin/advocc perf attack --json

clean:
	rm -rf $(VENV) build out .pytest_cache
