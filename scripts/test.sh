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
echo "== deploy: Dockerfile lint and workspace members, manifests, the pods' memory worst case"
CHECK_VENV="$PWD/.venv-deploy-check" bash deploy/check.sh
echo "== cargo build (release)"
cargo build --release --workspace --all-targets --locked
echo "== the Rust client builds without the simulator (no rapier in its dependency tree)"
if cargo tree -p unigait-client -e normal --locked | grep -E 'rapier|unigait-sim'; then
  echo "unigait-client depends on the simulator: replaying a recording needs unigait-rrd only" >&2
  exit 1
fi
echo "== cargo test (release)"
cargo test --release --workspace --locked
echo "== cargo clippy (-D warnings)"
cargo clippy --release --workspace --all-targets --locked -- -D warnings

if [ -f client-py/pyproject.toml ]; then
  ensure_python_env viz  # every extra the tests use: the live view and recordings need rerun
  echo "== ruff"
  "$VENV/bin/ruff" check client-py tests
  "$VENV/bin/ruff" check --config client-py/pyproject.toml scripts/check_links.py tools
  echo "== mypy"
  (cd client-py && "$VENV/bin/mypy" src/unigait)
  echo "== pytest"
  UNIGAIT_SERVER_BIN="$PWD/target/release/unigait-server" \
    UNIGAIT_CROSSCHECK_BIN="$PWD/target/release/unigait-crosscheck" \
    UNIGAIT_LEARNER_BIN="$PWD/target/release/unigait-learner" \
    "$VENV/bin/pytest" -q client-py/tests tests
  echo "== pytest against a non-editable install (the package carries its data files)"
  # The venv's install is editable (it reads the checkout); a user's wheel carries only what the
  # build copies. Build client-py from a clean copy (stale build/ or egg-info files would mask an
  # omission), install it without deps into a temp dir first on the path (the venv gives the
  # deps), and run the packaged-data tests against it, from that dir.
  installed="$(mktemp -d)"
  trap 'rm -rf "$installed"' EXIT
  mkdir "$installed/src"
  tar -c --exclude=build --exclude='*.egg-info' --exclude=_assets --exclude=_proto \
    --exclude=__pycache__ --exclude='.*_cache' client-py | tar -x -C "$installed/src"
  ln -s "$PWD/assets" "$PWD/proto" "$installed/src/"
  "$VENV/bin/pip" install -q --no-deps --no-build-isolation -c client-py/constraints.txt \
    --target "$installed/site" "$installed/src/client-py"
  packaged_tests="$PWD/client-py/tests/test_packaged_assets.py"
  (cd "$installed" && PYTHONPATH="$installed/site" UNIGAIT_INSTALLED_ROOT="$installed/site" \
    "$VENV/bin/python" -m pytest -q -p no:cacheprovider "$packaged_tests")
fi
