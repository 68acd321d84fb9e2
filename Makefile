# endo_stereo: plain entry points. WS = the git-ignored catkin workspace (default ./.ws: hidden, so that roslaunch/rostest file lookups, which skip dot-folders, do not follow the ws/src/endo_stereo symlink back into the repository).
SHELL := /bin/bash
WS ?= $(CURDIR)/.ws
export WS

.PHONY: all deps build test test-runner-selftest bench demo clean help asan tsan fuzz soak params-table

all: build

help:
	@echo "make demo   - install missing Debian packages, build, run the headless demo (outputs in out/demo)"
	@echo "make test   - install missing Debian packages, build, run every test (last line: N passed, N failed)"
	@echo "make test-runner-selftest - the test runner on planted defects (last line: runner self-test: N planted, N caught)"
	@echo "make bench  - build and run the benchmarks (ours vs OpenCV BM/SGBM, quasi-dense, stereo_image_proc)"
	@echo "make build  - build only;  make deps - install missing Debian packages only"
	@echo "make params-table - write the parameter table (src/core/pipeline/param_table.cpp) into README.md"
	@echo "make asan   - ASan+UBSan build in .ws_asan, whole test suite;  make tsan - TSan nodelet run in .ws_tsan"
	@echo "make fuzz   - libFuzzer harnesses, about a minute each;  make soak - 100000-pair soak (about an hour)"

deps:
	@scripts/install_deps.sh

build: deps
	@scripts/build.sh

test: deps
	@scripts/run_tests.sh

test-runner-selftest: build
	@scripts/runner_selftest.sh

bench: build
	@scripts/bench.sh

demo: build
	@scripts/demo.sh

params-table: build
	@scripts/params_table.sh

# Reliability (RELIABILITY.md): sanitizer workspaces of their own, fuzzing outside catkin.
asan: deps
	@scripts/sanitize.sh asan

tsan: deps
	@scripts/sanitize.sh tsan

fuzz:
	@scripts/fuzz.sh run

soak: build
	@scripts/soak.sh

clean:
	rm -rf $(WS) out
