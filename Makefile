# The README's commands. Each installs what is missing (scripts/install-deps), builds in build/
# (Release with debug info) what it needs and runs.
BUILD ?= build
JOBS ?= $(shell nproc)
CMAKE_FLAGS ?=
ifeq ($(CI),true)
CMAKE_FLAGS += -DMESOSCAN_WERROR=ON
endif

.PHONY: all deps configure build demo test bench fuzz clean

all: build

deps:
	@bash scripts/install-deps --consumers

configure: deps
	@cmake -S . -B $(BUILD) -DCMAKE_BUILD_TYPE=RelWithDebInfo $(CMAKE_FLAGS) >/dev/null

build: configure
	@cmake --build $(BUILD) -j $(JOBS)

# The demo builds only what it runs: the mesoscan executable with its modules and the Blender
# add-on zip (not the tests, benchmarks or fuzzers: `make test` and `make bench` build those).
demo: configure
	@cmake --build $(BUILD) -j $(JOBS) --target mesoscan
	@bash scripts/demo $(BUILD)

test: build
	@cd $(BUILD) && ctest --output-on-failure -j $(JOBS) --timeout 900

bench: build
	@bash scripts/bench $(BUILD)

# libFuzzer targets (fuzz/) built with clang in build-fuzz/, each run FUZZ_SECONDS (default 60).
FUZZ_SECONDS ?= 60
fuzz: deps
	@bash scripts/fuzz $(FUZZ_SECONDS)

clean:
	rm -rf $(BUILD) build-asan build-fuzz
