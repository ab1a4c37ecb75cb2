#!/usr/bin/env bash
# Profile-guided build of unigait-server (opt-in; docs/src/performance.md).
#
# 1. builds an instrumented server, 2. runs the simulation bench on the loops a training run
# and the MuJoCo comparison step (task loop, reference loop, curriculum terrain) to record where
# the time goes, 3. merges the profiles, 4. builds the server again using them.
# Two cold release builds (~20 min each on 2 cores); prints the optimised binary's path.
#
#   ./scripts/build_pgo.sh    # -> target/pgo/optimised/<host triple>/release/unigait-server
#
# rustc 1.95 writes LLVM 22 raw profiles; Debian's default llvm-profdata (14) cannot read them,
# llvm-profdata 19 can, and rustc reads what 19 writes. Set LLVM_PROFDATA to use another one.
set -euo pipefail
cd "$(dirname "$0")/.."

profdata="${LLVM_PROFDATA:-}"
if [[ -z "$profdata" ]]; then
  if [[ ! -x /usr/lib/llvm-19/bin/llvm-profdata ]]; then
    echo "installing llvm-19 for llvm-profdata" >&2
    sudo_cmd=""
    [[ $(id -u) -ne 0 ]] && sudo_cmd="sudo"
    $sudo_cmd apt-get install -y --no-install-recommends llvm-19 >/dev/null
  fi
  profdata=/usr/lib/llvm-19/bin/llvm-profdata
fi

target="${PGO_TARGET_DIR:-$PWD/target/pgo}"
# An explicit --target keeps RUSTFLAGS off build scripts and proc macros (they would write
# profiles of the build itself).
triple="$(rustc -vV | sed -n 's/^host: //p')"
profiles="$target/profiles"
rm -rf "$profiles"
mkdir -p "$profiles"

RUSTFLAGS="-Cprofile-generate=$profiles" \
  cargo build --release --locked -p unigait-server --target "$triple" --target-dir "$target/instrumented"

instrumented="$target/instrumented/$triple/release/unigait-server"
for loop in "" "--reference-loop" "--terrain curriculum --level 5"; do
  # shellcheck disable=SC2086 # the loop's flags are separate words
  "$instrumented" bench --envs 256 --steps 150 --threads 1 --actions random $loop >/dev/null
done
"$instrumented" bench --envs 256 --steps 150 --threads 1 --actions stand >/dev/null

"$profdata" merge -o "$profiles/merged.profdata" "$profiles"

RUSTFLAGS="-Cprofile-use=$profiles/merged.profdata" \
  cargo build --release --locked -p unigait-server --target "$triple" --target-dir "$target/optimised"

echo "$target/optimised/$triple/release/unigait-server"
