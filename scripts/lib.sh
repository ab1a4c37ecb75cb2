# Shared helpers for the scripts (sourced, not run).
VENV="${VENV:-$PWD/.venv}"

ensure_rust_tools() {
  if ! command -v cargo >/dev/null; then
    echo "cargo not found: this project needs the Rust toolchain (rustc 1.95)" >&2
    exit 1
  fi
  for component in rustfmt clippy; do
    rustup component list --installed 2>/dev/null | grep -q "^$component" || rustup component add "$component" >/dev/null 2>&1 || true
  done
}

# System packages the tests use (the TLS test makes a certificate with openssl).
ensure_system_packages() {
  if ! command -v openssl >/dev/null; then
    apt-get update -qq && apt-get install -y -qq openssl >/dev/null
  fi
  # The docs' book builder. Debian 12 packages no mdbook, so cargo builds it once per machine
  # (3 min 11 s here); 0.5.4 needs rustc >= 1.88. Its live-reload server is for writers: left out.
  local mdbook_version=0.5.4
  if ! mdbook --version 2>/dev/null | grep -qx "mdbook v$mdbook_version"; then
    cargo install mdbook --version "$mdbook_version" --locked --quiet \
      --no-default-features --features search
  fi
}

# Create the repo's venv and install the Python client with its extras (plus any given extras),
# at the exact versions of client-py/constraints.txt (pyproject.toml holds only ranges).
ensure_python_env() {
  local extras="dev,torch,rsl-rl,gymnasium,mujoco,ray"
  for e in "$@"; do extras="$extras,$e"; done
  if [ ! -x "$VENV/bin/python" ]; then
    python3 -m venv "$VENV"
  fi
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q -c client-py/constraints.txt -e "./client-py[$extras]"
}
