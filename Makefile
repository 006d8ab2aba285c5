# advocc_ros: `make demo` runs the main job, `make test` the tests. Both create .venv on demand.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.advocc-installed
WHEELS_STAMP  := $(VENV)/.advocc-wheels
MSGS_STAMP    := $(VENV)/.advocc-msgs
KERNELS_STAMP := $(VENV)/.advocc-kernels
MSGS   := $(shell find msg_defs -type f | sort)
OUT    ?= out/demo
PYTEST_ARGS ?=
FUZZ_INPUTS ?= 10000
# MPlib (an outside victim) needs numpy < 2: its own venv, used by one worker process.
MPLIB_VENV  ?= .venv-mplib
MPLIB_STAMP := $(MPLIB_VENV)/.advocc-mplib-installed
# OMPL 2.0.1 (AORRTC) shares the module name `ompl` with our 1.7.0 and its PRM* deadlocks with
# Python checkers: the aorrtc/rrtconnect2 victims run our planning worker in their own venv.
OMPL2_VENV  ?= .venv-ompl2
OMPL2_STAMP := $(OMPL2_VENV)/.advocc-ompl2-installed
# Planner Arena (OMPL's benchmark viewer, a Shiny app on pandas/polars/plotnine) reads the bench's
# benchmark.db in test/test_planner_arena.py only: its own venv, made by `make test`, not install.
ARENA_VENV  ?= .venv-arena
ARENA_STAMP := $(ARENA_VENV)/.advocc-arena-installed

.PHONY: install demo test test-fast fuzz perf clean

# The venvs are independent: they install side by side (mostly downloads and unpacking).
ENVS_JOBS ?= 4
# uv installs the pinned wheels into the venvs: it downloads in parallel and links the files of
# its one cache into all four, several times faster than pip (docs/usage.md, "How the install works"). The .venv's own
# pip installs uv itself from PyPI into build/uv (a standalone binary): a system Python may
# have no pip, or refuse installs outside a venv (PEP 668), but every venv has one. No
# --compile-bytecode: Python compiles the modules a process imports on first import, a fraction
# of the four venvs' 22,000 files (compiling them all took 115 s of CPU, 60 s of a 2-core install),
# and writes them once, so the install and the tests do not inherit PYTHONDONTWRITEBYTECODE
# (set, every one of the tests' processes would compile its imports again).
unexport PYTHONDONTWRITEBYTECODE
UV_VERSION ?= 0.13.9
UV         := build/uv/bin/uv
UV_INSTALL := $(UV) pip install --quiet

install:
	$(MAKE) --no-print-directory -j$(ENVS_JOBS) $(STAMP) $(MPLIB_STAMP) $(OMPL2_STAMP)

$(UV): | $(PY)
	$(PY) -m pip install --quiet --disable-pip-version-check --target build/uv uv==$(UV_VERSION)

$(PY):
	@$(PYTHON) -c 'import sys; assert sys.version_info[:2] == (3, 11), \
	  "advocc_ros needs Python 3.11 (the ROS 2 Jazzy wheels are cp311); set PYTHON=..."'
	$(PYTHON) -m venv $(VENV)

# One stamp for the whole environment: pinned wheels, OMPL fix-up, interfaces, our package, and
# its C kernels built into the user's cache (~2 s, not in a user's first attack; it needs only
# the wheels, so it runs beside the interfaces' build).
# ompl 1.7.0's wheel ships a stray second libompl next to the one its extensions link; loading
# both destroys OMPL's statics twice and every interpreter segfaults at exit: remove the stray.
$(WHEELS_STAMP): $(PY) setup.py setup.cfg package.xml Makefile | $(UV)
	$(UV_INSTALL) --python $(PY) -e '.[build,test,victims]'
	rm -f $$($(PY) -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/libompl.so*
	touch $@

$(MSGS_STAMP): $(WHEELS_STAMP) $(MSGS)
	msg_defs/build_into_venv.sh $(VENV) build/advocc_msgs
	touch $@

$(KERNELS_STAMP): $(WHEELS_STAMP)
	$(PY) -m advocc_ros.kernels
	touch $@

# Importing the CLI's attack also writes the bytecode of nearly every module an attack loads (make
# unexports PYTHONDONTWRITEBYTECODE), so a shell or image that sets it does not compile them in
# every attack (0.4 s of a 1.2 s warm attack, docs/performance.md).
$(STAMP): $(WHEELS_STAMP) $(MSGS_STAMP) $(KERNELS_STAMP)
	$(PY) -c 'import advocc_msgs.srv, rclpy, pinocchio, coal, ompl.geometric, advocc_ros.commands.attack'
	@echo "advocc_ros installed in $(VENV)"
	touch $@

# The MPlib victim's interpreter (advocc_ros/planning/victims/mplib_worker.py runs in it).
$(MPLIB_STAMP): Makefile | $(UV)
	$(PYTHON) -m venv $(MPLIB_VENV)
	$(UV_INSTALL) --python $(MPLIB_VENV)/bin/python \
	  mplib==0.2.1 numpy==1.26.4 toppra==0.6.10 transforms3d==0.4.2
	$(MPLIB_VENV)/bin/python -c 'import mplib, numpy; assert numpy.__version__ < "2"'
	@echo "MPlib victim installed in $(MPLIB_VENV)"
	touch $@

# The OMPL 2 victims' interpreter: OMPL 2.0.1 and what our planning worker imports (the same
# pins as setup.py's RUNTIME), never our package or ROS (the worker gets the source on PYTHONPATH).
$(OMPL2_STAMP): Makefile | $(UV)
	$(PYTHON) -m venv $(OMPL2_VENV)
	$(UV_INSTALL) --python $(OMPL2_VENV)/bin/python ompl==2.0.1 \
	  numpy==2.4.6 pin==4.1.0 coal==3.0.3 scipy==1.17.1 trimesh==5.2.0 pyyaml==6.0.3 \
	  example-robot-data==6.0.0
	$(OMPL2_VENV)/bin/python -c 'import ompl.geometric as og, pinocchio, coal; og.AORRTC'
	@echo "OMPL 2 victims installed in $(OMPL2_VENV)"
	touch $@

$(ARENA_STAMP): Makefile | $(UV)
	$(PYTHON) -m venv $(ARENA_VENV)
	$(UV_INSTALL) --python $(ARENA_VENV)/bin/python plannerarena==1.0.1
	$(ARENA_VENV)/bin/python -c 'from plannerarena.database import load_database'
	@echo "Planner Arena installed in $(ARENA_VENV)"
	touch $@

demo: $(STAMP)
	$(VENV)/bin/advocc demo --out $(OUT)

test:
	$(MAKE) --no-print-directory -j$(ENVS_JOBS) $(STAMP) $(MPLIB_STAMP) $(OMPL2_STAMP) $(ARENA_STAMP)
	$(PY) -m pytest $(PYTEST_ARGS)

# The core tests without processes (no nodes, planning workers or CLI runs) and without the
# long ones (marked slow): a contributor's fast lane. `make test` (what CI runs) stays the whole suite.
test-fast: $(STAMP)
	ADVOCC_FAST_LANE=1 $(PY) -m pytest -m 'not processes and not slow' $(PYTEST_ARGS)

# Generated malformed inputs against every parser and both services (test/fuzz); fails on any
# crash, hang or wrongly accepted input. Report: out/fuzz/report.json.
fuzz: $(STAMP)
	PYTHONPATH=test$${PYTHONPATH:+:$$PYTHONPATH} $(PY) -m fuzz --inputs $(FUZZ_INPUTS) --out out/fuzz

perf: $(STAMP)
	$(VENV)/bin/advocc perf heatmap --json
	$(VENV)/bin/advocc perf attack --json

clean:
	rm -rf $(VENV) $(MPLIB_VENV) $(OMPL2_VENV) $(ARENA_VENV) build out .pytest_cache
