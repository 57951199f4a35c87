# The front door. `make demo` and `make test` do all set-up on a fresh Debian 12.
#   make setup   Debian packages (only missing ones) and the .venv with pinned packages
#   make runtime the C99 runtime lensrt (library, lensrt-psf, C tests) in build/runtime
#   make demo    the default lens (0001): paraxial table, drawings, its polynomial fit with
#                the fit-error report, the demo scene's specialised code, and its point
#                spread function at f/2, f/8 and f/32 to 1% error by the Fourier integrator
#                (EXR, PNG and a sheet of the three with scale bars, build/demo/psf/), at
#                f/8 on the GL device (Monte Carlo), and the paper's Figure 10: close-ups of
#                2004's ghost 0-2 coated against uncoated and 0001's full frame with its
#                star and ghosts, every image to 1% (build/demo/flare/), and a bank of PSFs over the frame on a Dask
#                LocalCluster with its contact sheet (build/demo/bank/)
#   make test    lint, the C tests and examples/embed (also under ASan/UBSan, and a minimal
#                build without EXR, OpenMP and GL), the C parsers under libFuzzer for 15 s
#                each, and the Python test suite (the TOML loaders under hypothesis too)
#   make docs    the documentation site (MkDocs, strict: a broken link or a lensrt.h function
#                missing from the C API page fails) into build/site; part of make test
#   make fuzz    the parsers fuzzed for longer (FUZZ_SECONDS per libFuzzer target,
#                FUZZ_EXAMPLES hypothesis examples)
#   make bench   ray-tracer throughput, generated-code speed, fit report, lensrt splat rate
#                (and tile-scheduled against run()), per-ray evaluation against exact tracing,
#                compiled-in Horner code against lensrt's set-up,
#                per-ray evaluation against the exact tracer, error against run time (the
#                cells integrator against Monte Carlo too, and flare_figure.py's default
#                full frame against its point-filter flare row: cells_bench.py; the Fourier
#                integrator against both on the demo's PSFs: fourier_bench.py), a 1920 x 1080
#                frame through a bank's PSFs (lensrt_image_run: image_bench.py), banks on Dask
#                (scaling 1 -> 2 workers, the scheduler's overhead: banks.md), and per generated
#                lens the adaptive fit against the full one of the same degrees (fit time, worst
#                PSF cell against exactly traced rays, table size, lensrt set-up and splat rate:
#                fits.md, lensrt-tables.txt), and seconds per committed ghost and per
#                visible ghost at the committed flares' settings, with its PSF against exact
#                ghost rays (ghosts.md), and a default `lensfit fit` of every lens of lensdb
#                and the imported fixtures: CPU s, worst PSF cell, table size, refusals
#                (sweep.md) (build/bench/)

PYTHON ?= /usr/bin/python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
DEMO_LENS ?= 0001

.PHONY: setup runtime demo test bench fuzz lint docs clean

# Seconds per libFuzzer target: a short budget in `make test`, a long one in `make fuzz`
FUZZ_TEST_SECONDS ?= 15
FUZZ_SECONDS      ?= 600
FUZZ_EXAMPLES     ?= 20000

RUNTIME_BUILD := build/runtime
ASAN_BUILD    := build/asan
# -O1, as AddressSanitizer's documentation advises for reasonable performance:
# the ASan ctest takes 164 s instead of 279 s at -O0 (2 cores, 2026-11-29)
ASAN_CFLAGS   := -g -O1
PSF           := $(RUNTIME_BUILD)/runtime/lensrt-psf
CMAKE_FLAGS   ?= -DCMAKE_BUILD_TYPE=Release -DLENSRT_NATIVE=ON

setup: $(STAMP)

$(STAMP): fit/requirements.lock fit/pyproject.toml runtime/python/pyproject.toml scripts/setup-system.sh
	bash scripts/setup-system.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r fit/requirements.lock
	@# The manufacturers' glass catalogs (lensfit.glass.manufacturers) are the data files
	@# of opticalglass; --no-deps because its declared deps pull in PySide6 (a GUI of
	@# hundreds of MB) and pandas, which lensfit does not use: xlrd and openpyxl are locked
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps opticalglass==1.1.1
	@# lensrt's Python binding, an installable package (Dask workers pip install it too).
	@# Editable: scikit-build-core (pinned above) builds nothing here, and the binding loads
	@# `make runtime`'s build/runtime/runtime/liblensrt.so; `pip install runtime/python`
	@# (no -e) builds a wheel with the library inside (README, Install)
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation \
		-e runtime/python
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps -e fit
	touch $@

# The C99 runtime (library, lensrt-psf, C tests) in build/runtime
runtime: setup
	@mkdir -p build
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
	$(VENV)/bin/lensfit report $(DEMO_LENS) -o build/demo/report --no-timing
	$(VENV)/bin/lensfit scene $(DEMO_LENS) scenes/demo.toml -o build/demo/scene-demo
	@mkdir -p build/demo/psf
	@# The paper's Figure 7: an off-axis light through the default lens, 7 curved blades.
	@# The Fourier integrator (lensrt-psf's default: nodes chosen from the phase, refined
	@# by --target-error if the printed estimate were above 1%), then the three side by side
	panels=; for fn in 2 8 32; do \
		case $$fn in 2) size=0.2;; 8) size=0.1;; 32) size=0.16;; esac; \
		$(PSF) --lens $(DEMO_LENS) --light -6,-4 --focus 0.2 --f-number $$fn --blades 7 \
			--curvature 0.3 --rotation 10 --size $$size --resolution 256x256 \
			--integrator auto --target-error 0.01 \
			-o build/demo/psf/f$$fn.exr --png build/demo/psf/f$$fn.png || exit 1; \
		panels="$$panels --panel build/demo/psf/f$$fn.png $$size f/$$fn"; \
	done; \
	$(PY) runtime/tools/psf_sheet.py -o build/demo/psf/sheet.png $$panels \
		--title "lens $(DEMO_LENS), light at (-6°, -4°), 7 curved blades, sensor 0.2 mm behind focus, 16 wavelengths"
	@# The f/8 scene again on the GL device (OpenGL 4.3 compute shaders; llvmpipe on a
	@# machine without a GPU, so smaller here); exit status 3 means no GL device
	$(PSF) --lens $(DEMO_LENS) --light -6,-4 --focus 0.2 --f-number 8 --blades 7 --curvature 0.3 \
		--rotation 10 --size 0.1 --resolution 64x64 --wavelengths 8 --samples 16384 --device gl \
		-o build/demo/psf/f8-gl.exr --png build/demo/psf/f8-gl.png \
		|| { rc=$$?; [ $$rc -eq 3 ] && echo "demo: no GL device here, the CPU renders above stand"; [ $$rc -eq 3 ]; }
	@# The paper's Figure 10 (issue 26): close-ups of the anamorphic 2004's ghost 0-2 (the
	@# reflection at its outer cylindrical element; light -6,-4 deg as its ghosts were fitted,
	@# f/16, 10 um pixels, box filter with lensrt's automatic counts), coated (the lens
	@# file's MgF2 quarter wave) and uncoated at one exposure; under them the full 36 x 24 mm
	@# frame of 0001 (2004's fitted sensor box, +-15.4 mm, cannot hold it) with 7 curved
	@# blades: the light saturated with its star (its window +-1.5 mm, automatic counts)
	@# and its ghosts (box filter at 2 x 2 points: footprints of many pixels). Every image
	@# to a 1% error estimate; about 2 min on 2 cores (the star's window is most of it)
	$(PY) runtime/tools/flare_figure.py -o build/demo/flare/figure10.png --light=-6,-4 \
		--wavelengths 8 --target-error 0.01 --blades 7 --curvature 0.3 --rotation 10 \
		--direct-half 1.5 --pixel-samples 2 \
		--closeup generated/2004-schneider-anamorphic "2004 coated" \
		--closeup generated/2004-schneider-anamorphic-uncoated "2004 uncoated" \
		--panel generated/0001-angenieux-double-gauss 16 "0001 coated" \
		--note "2004's fitted sensor box (+-15.4 mm) cannot hold the 36 x 24 mm frame: the full frame is the default lens 0001"
	@# lensrt-psf with the default lens's ghosts around its first: one EXR, the total with
	@# layers direct. and flare.; the direct image and ghost 0-2 by the Fourier integrator,
	@# each within auto's 1% (else cells, else exit 5); the ghosts whose footprints miss
	@# this small window (0-4, 2-4, 2-6) or that reach no sensor point (4-8) skipped, said
	$(PSF) --lens $(DEMO_LENS) --light -6,-4 --f-number 16 --center -10.1,-6.7 --size 1.2x0.8 \
		--resolution 96x64 --wavelengths 4 --integrator auto --rings 64 --quiet \
		--flares generated/0001-angenieux-double-gauss/ghosts \
		-o build/demo/flare/flares.exr --png build/demo/flare/flares.png
	@# A bank (issue 23): lens 0001 at f/8, 9 x 5 field points over the frame, 8
	@# wavelengths, each node to 1%, on a Dask LocalCluster; bank.index is what
	@# lensrt_bank_open reads, contact-sheet.png the picture to look at first. A rerun
	@# resumes (renders only unfinished nodes)
	LENSRT_LIBRARY=$(CURDIR)/$(RUNTIME_BUILD)/runtime/liblensrt.so \
		$(VENV)/bin/lensfit bank banks/demo.toml -o build/demo/bank --restart
	@# A whole frame through the lens (issue 38): a night street rendered by Mitsuba 3
	@# (a pinhole of lens 0001's focal length on a 36 mm wide sensor), through lens 0001 at
	@# f/8: every pixel by its own field point's PSF (a bank over the frame, built once and
	@# cached in build/image-cache), and the brightest lamp's ghosts; then pinhole | through
	@# the lens | flare side by side (docs/image.md)
	@mkdir -p build/demo/image
	$(PY) scenes/night_street.py -o build/demo/image/street.exr --focal-mm 99.9507
	LENSRT_LIBRARY=$(CURDIR)/$(RUNTIME_BUILD)/runtime/liblensrt.so \
		$(VENV)/bin/lensfit image $(DEMO_LENS) build/demo/image/street.exr \
		-o build/demo/image/street-lens.exr --png build/demo/image/street-lens.png \
		--f-number 8 --ghosts kept --max-sources 1 --flare-target-error 0.05
	$(PY) runtime/tools/image_sheet.py -o build/demo/image/sheet.png \
		--title "lens $(DEMO_LENS) at f/8: pinhole | through the lens | flare (the brightest lamp's ghosts)" \
		--panel build/demo/image/street.exr "pinhole (Mitsuba 3)" \
		--panel build/demo/image/street-lens.exr "through lens $(DEMO_LENS), f/8" \
		--panel build/demo/image/street-lens.exr:flare "flare layer"

lint: setup
	$(VENV)/bin/ruff check --config fit/pyproject.toml fit tests runtime/python runtime/bench runtime/tools docs/gen
	@# lensfit's import structure (fit/pyproject.toml [tool.importlinter]): no import cycle,
	@# the packages layered in the data flow's order. PYTHONPATH=fit: this checkout's lensfit
	PYTHONPATH=fit $(VENV)/bin/lint-imports --config fit/pyproject.toml --no-cache

# The documentation site (docs/about.md): docs/*.md, and pages generated at build time by
# docs/gen/*.py from lensrt.h, the Python packages, the CLI parsers (and the runtime's
# tools' --help, hence runtime) and docs/benchmarks/snapshots/. Strict: any warning fails.
docs: setup runtime
	DISABLE_MKDOCS_2_WARNING=true $(VENV)/bin/mkdocs build --strict -f mkdocs.yml

# ctest -j 2: the C tests are independent (each its own scratch folder) and mostly one
# thread each, so two at a time take the two cores (the ASan build's 160 s become ~90 s)
test: setup lint runtime docs
	ctest --test-dir $(RUNTIME_BUILD) --output-on-failure -j 2
	cmake -S . -B $(ASAN_BUILD) -DCMAKE_BUILD_TYPE=Debug -DLENSRT_SANITIZE=ON "-DCMAKE_C_FLAGS_DEBUG=$(ASAN_CFLAGS)" \
		> $(ASAN_BUILD).configure.log 2>&1 \
		|| (cat $(ASAN_BUILD).configure.log; exit 1)
	cmake --build $(ASAN_BUILD) -j 2
	ctest --test-dir $(ASAN_BUILD) --output-on-failure -j 2
	cmake -S . -B build/minimal -DLENSRT_WITH_EXR=OFF -DLENSRT_WITH_OPENMP=OFF -DLENSRT_WITH_GL=OFF \
		> build/minimal.configure.log 2>&1 \
		|| (cat build/minimal.configure.log; exit 1)
	cmake --build build/minimal -j 2
	ctest --test-dir build/minimal --output-on-failure -j 2
	bash tests/fuzz/run.sh $(FUZZ_TEST_SECONDS)
	@# Two workers, each taking whole test files (module fixtures are computed once)
	$(PY) -m pytest tests -n 2 --dist loadfile --durations=15

# The parsers under fuzzing for longer: the lens table and phasor readers (libFuzzer with
# ASan/UBSan, build/fuzz/), the TOML loaders and the .zmx/Optiland importers (hypothesis)
fuzz: setup
	bash tests/fuzz/run.sh $(FUZZ_SECONDS)
	LENSFIT_FUZZ_EXAMPLES=$(FUZZ_EXAMPLES) $(PY) -m pytest tests/fit/test_fuzz_toml.py \
		tests/fit/interchange/test_fuzz_import.py -q

bench: setup runtime
	@mkdir -p build/bench
	$(RUNTIME_BUILD)/runtime/lensrt-bench --json build/bench/lensrt.json
	$(PY) runtime/bench/eval_bench.py --library $(RUNTIME_BUILD)/runtime/liblensrt.so --out build/bench
	cmake --build $(RUNTIME_BUILD) -j 2 --target lensrt-compiled-bench
	$(RUNTIME_BUILD)/runtime/lensrt-compiled-bench | tee build/bench/compiled.txt
	$(PY) runtime/bench/error_vs_time.py --out build/bench --lensrt-json build/bench/lensrt.json
	$(PY) runtime/bench/flare_bench.py --library $(RUNTIME_BUILD)/runtime/liblensrt.so --out build/bench
	$(PY) runtime/bench/cells_bench.py --library $(RUNTIME_BUILD)/runtime/liblensrt.so --out build/bench
	$(PY) runtime/bench/fourier_bench.py --library $(RUNTIME_BUILD)/runtime/liblensrt.so --out build/bench
	$(PY) runtime/bench/image_bench.py --library $(RUNTIME_BUILD)/runtime/liblensrt.so --out build/bench
	LENSRT_LIBRARY=$(CURDIR)/$(RUNTIME_BUILD)/runtime/liblensrt.so $(PY) -m lensfit.banks.bench --out build/bench
	$(PY) -m lensfit.cli.bench --out build/bench
	$(PY) -m lensfit.codegen.bench | tee build/bench/codegen.txt
	$(VENV)/bin/lensfit report $(DEMO_LENS) -o build/bench/fit-$(DEMO_LENS) --json \
		> build/bench/fit-$(DEMO_LENS).json
	LENSRT_LIBRARY=$(CURDIR)/$(RUNTIME_BUILD)/runtime/liblensrt.so $(PY) -m lensfit.cli.bench --fits --out build/bench
	@# lensrt's splat rate against its scalar baseline on each lens's two tables, adaptive
	@# and full, from the fits just made (issue 24: the smaller table must not be slower)
	for t in 0001 0009; do for m in full adaptive; do echo "== $$t $$m"; \
		$(RUNTIME_BUILD)/runtime/lensrt-bench --device cpu --repeats 3 --tile 0x0 \
		--table build/bench/fit-tables/$$t-$$m.table --json build/bench/lensrt-$$t-$$m.json \
		| grep -A4 '^f/N'; done; done | tee build/bench/lensrt-tables.txt
	$(PY) -m lensfit.cli.bench --ghosts --out build/bench
	@# A whole frame through the lens (issue 38): the 1080p frame's stages cold and cached,
	@# and a window against every lit pixel's own PSF at four settings: image.md
	LENSRT_LIBRARY=$(CURDIR)/$(RUNTIME_BUILD)/runtime/liblensrt.so $(PY) -m lensfit.image.bench --out build/bench
	@# Every lens of lensdb (coated and uncoated) and the imported fixtures, fitted with
	@# defaults one at a time (CPU seconds of each fit alone; at most 300 each): sweep.md
	$(PY) -m lensfit.pipeline.sweep --out build/bench --workers 1 --cpu-limit 300
	@# The slow physics checks (`-m slow`: each has a faster sibling in `make test`), and
	@# exact-ray PSFs against Optiland's Huygens PSF at every stop position and field
	@# (issue 36; `make test` runs three of the eight)
	$(PY) -m pytest tests -m slow -q \
		| tee build/bench/slow-tests.txt
	@# Last: the summaries above (build/bench/*.md, *.txt) copied into the docs as dated
	@# snapshots (docs/benchmarks/snapshots/, pages of the site); commit those that changed
	$(PY) docs/gen/collect_bench.py --from build/bench --to docs/benchmarks/snapshots

clean:
	rm -rf build $(VENV)
