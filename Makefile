# The front door. `make demo` and `make test` do all set-up on a fresh Debian 12.
#   make setup   Debian packages (only missing ones) and the .venv with pinned packages
#   make demo    the default lens (0001): paraxial table, drawings, its polynomial fit with
#                the fit-error report, and the demo scene's specialised code
#   make test    lint and the test suite
#   make bench   ray-tracer throughput, generated-code speed, fit report (build/bench/)

PYTHON ?= /usr/bin/python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
DEMO_LENS ?= 0001

.PHONY: setup runtime demo test bench lint clean

RUNTIME_BUILD := build/runtime
CMAKE_FLAGS   ?= -DCMAKE_BUILD_TYPE=Release -DLENSRT_NATIVE=ON

setup: $(STAMP)

$(STAMP): fit/requirements.lock fit/pyproject.toml scripts/setup-system.sh
	bash scripts/setup-system.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r fit/requirements.lock
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps -e fit
	touch $@

# The C99 runtime (library, lensrt-psf, C tests) in build/runtime
runtime: setup
	cmake -S . -B $(RUNTIME_BUILD) $(CMAKE_FLAGS) > $(RUNTIME_BUILD).configure.log 2>&1 \
		|| (cat $(RUNTIME_BUILD).configure.log; exit 1)
	cmake --build $(RUNTIME_BUILD) -j 2

demo: setup runtime
	@mkdir -p build/demo
	$(VENV)/bin/lensfit info $(DEMO_LENS)
	$(VENV)/bin/lensfit info $(DEMO_LENS) --json > build/demo/$(DEMO_LENS).json
	$(VENV)/bin/lensfit draw $(DEMO_LENS) -o build/demo/$(DEMO_LENS).png
	$(VENV)/bin/lensfit draw $(DEMO_LENS) --f-number 8 --field 15 -o build/demo/$(DEMO_LENS)-f8.png
	$(VENV)/bin/lensfit check
	$(VENV)/bin/lensfit report $(DEMO_LENS) -o build/demo/report
	$(VENV)/bin/lensfit scene $(DEMO_LENS) scenes/demo.toml -o build/demo/scene-demo

lint: setup
	$(VENV)/bin/ruff check --config fit/pyproject.toml fit tests

test: setup lint
	$(PY) -m pytest tests

bench: setup
	@mkdir -p build/bench
	$(PY) -m lensfit.bench --out build/bench
	$(PY) -m lensfit.codegen.bench | tee build/bench/codegen.txt
	$(VENV)/bin/lensfit report $(DEMO_LENS) -o build/bench/fit-$(DEMO_LENS) --json \
		> build/bench/fit-$(DEMO_LENS).json

clean:
	rm -rf build $(VENV)
