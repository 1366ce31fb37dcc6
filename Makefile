# scanreg developer tasks. `make demo` and `make test` are the README's two commands: each
# creates .venv (if missing), builds the Rust core in release mode and installs scanreg
# editable into it — `demo` with no optional extra, `test` (through `dev`) with every extra.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
PY_SRC := python tests benchmarks examples docs fuzz

.PHONY: build dev demo test lint lint-rust lint-python test-rust test-python bench clean system-check

$(BIN)/maturin:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q 'maturin>=1.7,<2'

# Re-running is cheap: cargo rebuilds only what changed.
build: $(BIN)/maturin
	$(BIN)/python -m pip install -q --no-build-isolation -e .

# Debian packages some tests load (open3d-cpu: libusb-1.0; the report's browser test: chromium):
# installed when missing and running as root, else named with the command to run.
system-check:
	.ci/system-packages

dev: $(BIN)/maturin system-check
	$(BIN)/python -m pip install -q --no-build-isolation -e '.[dev]'

demo: build
	$(BIN)/scanreg demo

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

test: lint test-rust test-python

bench: dev
	$(BIN)/python benchmarks/run_all.py $(if $(wildcard /tmp/peers-venv),--peers-site $(wildcard /tmp/peers-venv/lib/python3.*/site-packages))

clean:
	rm -rf $(VENV) target python/scanreg/*.so
