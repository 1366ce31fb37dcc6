# scanreg developer tasks. `make demo` and `make test` are the README's two commands: each
# creates .venv (if missing), builds the Rust core in release mode and installs scanreg
# editable into it.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
PY_SRC := python tests benchmarks examples docs

.PHONY: dev demo test lint lint-rust lint-python test-rust test-python bench clean

$(BIN)/maturin:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q 'maturin>=1.7,<2'

# Re-running is cheap: cargo rebuilds only what changed.
dev: $(BIN)/maturin
	$(BIN)/python -m pip install -q --no-build-isolation -e '.[dev]'

demo: dev
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
