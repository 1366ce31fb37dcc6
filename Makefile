# scanreg developer tasks. `make demo` and `make test` are the README's two commands: each
# creates .venv (if missing), builds the Rust core in release mode and installs scanreg
# editable into it — `demo` with the extras its mapping and report need, `test` (through
# `dev`) with every extra. `make wheel` builds what `pip install scanreg` installs.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
PY_SRC := python tests benchmarks examples docs fuzz
# maturin finds zig (the `ziglang` package) as `python3 -m ziglang` on PATH: the venv's.
export PATH := $(abspath $(BIN)):$(PATH)
# Every build of the core links through zig against glibc 2.17 (manylinux2014): the editable
# install (`build`, `dev`, `demo`) and the wheel then run the same cargo build, so `make wheel`
# after `make test` reuses it and costs seconds instead of a second release build.
ZIG_ARGS := --zig --compatibility manylinux2014
# The core is now `_core.abi3.so`; a stale `_core.cpython-3XX-….so` from an older build would be
# imported before it, so it is removed first.
EDITABLE := rm -f python/scanreg/_core.cpython-*.so && \
	MATURIN_PEP517_ARGS="$(ZIG_ARGS)" $(BIN)/python -m pip install -q --no-build-isolation -e
ZIG_STAMP := $(VENV)/.ziglang
WHEEL_VENV := target/wheel-venv

.PHONY: build dev demo test lint lint-rust lint-python test-rust test-python test-wheel wheel bench clean system-check

$(BIN)/maturin:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q 'maturin>=1.7,<2'

# zig as a wheel from PyPI: the linker for glibc 2.17, no system toolchain needed.
$(ZIG_STAMP): $(BIN)/maturin
	$(BIN)/python -m pip install -q 'ziglang>=0.13'
	touch $@

# Re-running is cheap: cargo rebuilds only what changed.
build: $(ZIG_STAMP)
	$(EDITABLE) .

# Debian packages some tests load (open3d-cpu: libusb-1.0; the report's browser test: chromium):
# installed when missing and running as root, else named with the command to run.
system-check:
	.ci/system-packages

dev: $(ZIG_STAMP) system-check
	$(EDITABLE) '.[dev]'

# The demo maps with loop closure (gtsam: the `mapping` extra) and writes report.html
# (plotly: `report`); a plain `pip install scanreg` runs the rest and names what it skipped.
demo: $(ZIG_STAMP)
	$(EDITABLE) '.[mapping,report]'
	$(BIN)/scanreg demo --output runs/demo

# One abi3 wheel (CPython >= 3.10) tagged manylinux2014, and the sdist, into dist/.
wheel: $(ZIG_STAMP)
	rm -f dist/scanreg-*.whl dist/scanreg-*.tar.gz
	$(BIN)/maturin build --release $(ZIG_ARGS) --interpreter $(BIN)/python --out dist
	$(BIN)/maturin sdist --out dist

# The wheel installed into a fresh venv, run with no Rust toolchain on PATH from outside the
# source tree: first alone (the smoke test; the demo names the extras it skips), then with the
# demo's extras (the whole demo, its checks against the truth).
test-wheel: wheel
	.ci/test-wheel $(WHEEL_VENV)

lint-rust:
	cargo fmt --all --check
	cargo clippy --workspace --all-targets -- -D warnings

lint-python: dev
	$(BIN)/ruff check $(PY_SRC)
	$(BIN)/ruff format --check $(PY_SRC)
	$(BIN)/mypy
	$(BIN)/python -m mypy.stubtest scanreg._core --allowlist stubtest-allowlist.txt

lint: lint-rust lint-python

test-rust:
	cargo test -p scanreg-core
	# Also as shipped (opt-level 3, one codegen unit): a miscompilation of the 2D Censi normal
	# term showed only there (e778664).
	cargo test -p scanreg-core --release

test-python: dev
	$(BIN)/python -m pytest

test: lint test-rust test-python test-wheel

bench: dev
	$(BIN)/python benchmarks/run_all.py $(if $(wildcard /tmp/peers-venv),--peers-site $(wildcard /tmp/peers-venv/lib/python3.*/site-packages))

clean:
	rm -rf $(VENV) target dist python/scanreg/*.so
