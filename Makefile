# Two commands do all the set-up on a fresh machine: `make run` and `make test`.
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
SYSTEM := $(VENV)/.system-packages
HOST   ?= 127.0.0.1
PORT   ?= 9090
export MUJOCO_GL ?= egl

.PHONY: run test bench schema clean

run: $(STAMP)
	$(VENV)/bin/vr-teleop serve --host $(HOST) --port $(PORT)

test: $(STAMP)
	$(PY) -m pytest -q

bench: $(STAMP)
	$(PY) bench/run_all.py

schema: $(STAMP)
	$(VENV)/bin/vr-teleop schema --out client_protocol/schemas

# Debian packages: espeak-ng for text-to-speech, Mesa's EGL for MuJoCo's offscreen camera, Chromium for the
# dashboard's browser tests.
$(SYSTEM): scripts/install-system-packages.sh
	bash scripts/install-system-packages.sh
	mkdir -p $(VENV) && touch $@

$(STAMP): pyproject.toml $(SYSTEM)
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $@

clean:
	rm -rf $(VENV) *.egg-info .pytest_cache .hypothesis
