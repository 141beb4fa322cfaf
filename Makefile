# Two commands for a newcomer: `make demo` (set up, run the main job) and `make test` (set up, run the tests).
VENV ?= .venv
PYTHON ?= python3

.PHONY: setup demo test bench
setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml .ci/constraints.txt
	# Open3D (dev extra: cross-checks and PCD tests) needs libusb; install it from Debian when missing
	@ldconfig -p | grep -q libusb-1.0 || (apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1 || \
	  (apt-get update -q >/dev/null 2>&1 && apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1) || \
	  echo "warning: could not install libusb-1.0-0 (Debian); Open3D tests will fail")
	# headless Chromium (Debian's chromium package) opens the HTML report in its test
	@command -v chromium >/dev/null 2>&1 || (apt-get install -y -q chromium >/dev/null 2>&1 || \
	  (apt-get update -q >/dev/null 2>&1 && apt-get install -y -q chromium >/dev/null 2>&1) || \
	  echo "warning: could not install chromium (Debian); the report test will fail")
	$(PYTHON) -m venv $(VENV)
	# torch first, pinned: this machine's CPU wheel (a plain "torch" could pull a multi-GB CUDA build)
	$(VENV)/bin/pip install --quiet torch==2.13.0
	# the tested versions of everything else (.ci/constraints.txt): the same numbers on a fresh machine
	$(VENV)/bin/pip install --quiet -c .ci/constraints.txt -e '.[dev]'
	touch $@

demo: setup
	$(VENV)/bin/asg generate

test: setup
	$(VENV)/bin/pytest -q

bench: setup
	$(VENV)/bin/asg bench simulate
