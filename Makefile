# ompn_ros: every target sets itself up (.venv) and keeps DDS on this machine.
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
STAMP := $(VENV)/.ompn_ros_installed

# DDS containment: Fast DDS on shared memory + UDP bound to 127.0.0.1 only (the profile below;
# with LOCALHOST rmw_fastrtps would add an unrestricted UDP transport, hence SYSTEM_DEFAULT), no
# static peers, and every make run gets its own domain. Your own shells and launches are unaffected.
export FASTRTPS_DEFAULT_PROFILES_FILE := $(CURDIR)/config/fastdds_loopback.xml
export FASTDDS_DEFAULT_PROFILES_FILE := $(CURDIR)/config/fastdds_loopback.xml
export ROS_AUTOMATIC_DISCOVERY_RANGE := SYSTEM_DEFAULT
export ROS_STATIC_PEERS :=
unexport ROS_LOCALHOST_ONLY
ROS_DOMAIN_ID ?= $(shell shuf -i 1-100 -n 1)
export ROS_DOMAIN_ID
export PYTHONDONTWRITEBYTECODE := 1
export MUJOCO_GL ?= egl

.PHONY: setup demo test test-fast test-slow lint colcon bench doctor reproduce-craft reproduce-dial ship-craft ship-dial clean

setup: $(STAMP)

# Order matters: the CPU torch first (otherwise pip resolves a multi-GB CUDA build), then the
# ROS 2 Jazzy wheels, then the rest, then the messages (ompn_interfaces, built with CMake into the venv),
# then this package in editable mode.
INTERFACES := $(wildcard ompn_interfaces/msg/*.msg) ompn_interfaces/CMakeLists.txt ompn_interfaces/package.xml

$(STAMP): requirements.txt requirements-dev.txt setup.py setup.cfg package.xml $(INTERFACES)
	test -x $(PY) || python3 -m venv $(VENV)
	$(PIP) install --quiet --upgrade pip
	$(PIP) install --quiet torch==2.13.0
	$(PIP) install --quiet 'ros-jazzy-rclpy[fastrtps]==7.1.6' 'ros-jazzy-common-interfaces==5.3.6'
	$(PIP) install --quiet -r requirements-dev.txt
	$(PIP) install --quiet -r ompn_interfaces/requirements-venv.txt
	$(PY) ompn_interfaces/build_venv.py
	$(PIP) install --quiet --no-deps --no-build-isolation -e .
	$(PY) -m ompn_ros.model._jit_stream
	touch $(STAMP)

demo: setup
	$(PY) -m ompn_ros.cli.demo

test: setup
	$(PY) -m pytest test -m "not slow" -q -p no:cacheprovider

test-fast: setup
	$(PY) -m pytest test -m "not slow and not ros and not integration" -q -p no:cacheprovider

test-slow: setup
	$(PY) -m pytest test -m slow -q -p no:cacheprovider

lint: setup
	$(VENV)/bin/ruff check ompn_ros sim_nodes lab test bench examples
	$(VENV)/bin/mypy

colcon: setup
	source $(VENV)/bin/activate && AMENT_PREFIX_PATH=$$VIRTUAL_ENV CMAKE_PREFIX_PATH=$$VIRTUAL_ENV \
	  colcon build --base-paths . ompn_interfaces --build-base build --install-base install

bench: setup
	$(PY) bench/run_all.py
	$(PY) bench/report.py

.PHONY: bench-own-robot
bench-own-robot: setup
	$(PY) bench/bench_own_robot.py

doctor: setup
	$(PY) -m ompn_ros.cli.demo --smoke

# The reproduction through the product: ompn_collect, ompn_train (fixed updates, every other default,
# the detector it bundles), ompn_segment on held-out demonstrations, per setting and seed
# (lab/reproduce_product.py).  The lab's in-process study (ensembles, distillation, sweeps, its own
# detector tuning): $(PY) -m lab.reproduce craft --members full_nosketch=3,partial_nosketch=3
reproduce-craft reproduce-dial: reproduce-%: setup
	$(PY) -m lab.reproduce_product $*

# The shipped checkpoints: ompn_collect, ompn_train (current config and defaults, the detector it
# chooses), ompn_segment on held-out demonstrations, then copied into the package (lab/ship_product.py).
ship-craft ship-dial: ship-%: setup
	$(PY) -m lab.ship_product $*

clean:
	rm -rf build install log .pytest_cache .mypy_cache .ruff_cache *.egg-info
