# endo_stereo: plain entry points. WS = the git-ignored catkin workspace (default ./ws).
SHELL := /bin/bash
WS ?= $(CURDIR)/ws
export WS

.PHONY: all deps build test bench demo clean help

all: build

help:
	@echo "make demo   - install missing Debian packages, build, run the headless demo (outputs in out/demo)"
	@echo "make test   - install missing Debian packages, build, run every test (last line: N passed, N failed)"
	@echo "make bench  - build and run the benchmarks (ours vs OpenCV BM/SGBM, quasi-dense, stereo_image_proc)"
	@echo "make build  - build only;  make deps - install missing Debian packages only"

deps:
	@scripts/install_deps.sh

build: deps
	@scripts/build.sh

test: deps
	@scripts/run_tests.sh

bench: build
	@scripts/bench.sh

demo: build
	@scripts/demo.sh

clean:
	rm -rf $(WS) out
