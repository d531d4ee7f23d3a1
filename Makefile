# Two commands do all the set-up on a fresh machine: `make run` and `make test`.
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
SYSTEM := $(VENV)/.system-packages
HOST   ?= 127.0.0.1
PORT   ?= 9090
export MUJOCO_GL ?= egl

.PHONY: run test check test-runs bench schema docs docs-serve screenshots clean

run: $(STAMP)
	$(VENV)/bin/vr-teleop serve --host $(HOST) --port $(PORT)

# The suite on TEST_WORKERS processes (pytest-xdist), each module whole on one of them, so that a module's shared
# server is started once; TEST_WORKERS=0 runs it in this process.
TEST_WORKERS ?= 2
test: $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

# The quick loop while working: everything but the browser, network-namespace and slow tests (at most 5 minutes).
check: $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m "not slow and not browser and not netns"

# The whole suite RUNS times in a row on a fresh clone of HEAD, each run's result and time reported.
RUNS ?= 5
test-runs: $(STAMP)
	$(PY) scripts/suite_runs.py --runs $(RUNS) --workers $(TEST_WORKERS) --python $(PY)

bench: $(STAMP)
	$(PY) bench/run_all.py

schema: $(STAMP)
	$(VENV)/bin/vr-teleop schema --out client_protocol/schemas --names-js vr_teleop_server/web/names.js

# The documentation site (MkDocs, Material theme) into site/; the reference pages are generated while it builds.
# (NO_MKDOCS_2_WARNING: Material's banner about MkDocs 2, which the docs extra's bounds exclude.)
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --site-dir site

docs-serve: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs serve --strict --dev-addr $(HOST):8000

# The pictures the documentation shows, from the real pages on the stand-in (Chromium through Playwright).
screenshots: $(STAMP)
	$(PY) scripts/screenshots.py --out docs/images

# Debian packages: espeak-ng for text-to-speech, Mesa's EGL for MuJoCo's offscreen camera, Chromium for the
# dashboard's browser tests, Node's npm for the operator page's JavaScript.
$(SYSTEM): scripts/install-system-packages.sh
	bash scripts/install-system-packages.sh
	mkdir -p $(VENV) && touch $@

# The operator page's JavaScript (three.js, pinned in package.json/package-lock.json) is copied into the package, so
# the page loads nothing from the internet; `npm ci` also brings IWER, the emulated headset of the browser tests.
WEB_VENDOR := vr_teleop_server/web/vendor/three/three.module.js
$(WEB_VENDOR): package.json package-lock.json $(SYSTEM)
	npm ci --no-audit --no-fund --loglevel=error
	mkdir -p $(@D)
	cp node_modules/three/build/three.module.js node_modules/three/build/three.core.js node_modules/three/LICENSE $(@D)/
	touch $@

# A .venv made before the face detector holds opencv-python-headless, which opencv-python replaces: both install the
# one cv2 package, so both go before the install brings opencv-python back alone.
$(STAMP): pyproject.toml $(SYSTEM) $(WEB_VENDOR)
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	if $(PY) -m pip show --quiet opencv-python-headless 2>/dev/null; then \
	  $(PY) -m pip uninstall --quiet --yes opencv-python-headless opencv-python; fi
	$(PY) -m pip install --quiet -e '.[test,docs]'
	touch $@

clean:
	rm -rf $(VENV) site *.egg-info .pytest_cache .hypothesis node_modules vr_teleop_server/web/vendor
