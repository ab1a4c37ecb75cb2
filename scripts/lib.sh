# Shared helpers for the scripts (sourced, not run).
VENV="${VENV:-$PWD/.venv}"

ensure_rust_tools() {
  if ! command -v cargo >/dev/null; then
    echo "cargo not found: this project needs the Rust toolchain (rustc 1.95)" >&2
    exit 1
  fi
  rustup component list --installed 2>/dev/null | grep -q rustfmt || rustup component add rustfmt >/dev/null 2>&1 || true
}

ensure_python_env() {
  if [ ! -x "$VENV/bin/python" ]; then
    python3 -m venv "$VENV"
  fi
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q -e "./client-py[dev,torch,rsl_rl,gymnasium]"
}
