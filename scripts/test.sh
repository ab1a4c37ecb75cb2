#!/usr/bin/env bash
# Set up and run every test: Rust workspace (one release profile) and, when present, the Python
# client against the real server binary. Installs what it needs; safe to run repeatedly.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/lib.sh

ensure_rust_tools
ensure_system_packages
echo "== cargo fmt --check"
cargo fmt --all -- --check
echo "== docs: mdbook build, link check"
mdbook build docs
python3 scripts/check_links.py
echo "== cargo build (release)"
cargo build --release --workspace --all-targets --locked
echo "== cargo test (release)"
cargo test --release --workspace --locked
echo "== cargo clippy (-D warnings)"
cargo clippy --release --workspace --all-targets --locked -- -D warnings

if [ -f client-py/pyproject.toml ]; then
  ensure_python_env
  echo "== ruff"
  "$VENV/bin/ruff" check client-py tests
  "$VENV/bin/ruff" check --config client-py/pyproject.toml scripts/check_links.py tools
  echo "== mypy"
  (cd client-py && "$VENV/bin/mypy" src/unigait)
  echo "== pytest"
  UNIGAIT_SERVER_BIN="$PWD/target/release/unigait-server" "$VENV/bin/pytest" -q client-py/tests tests
fi
