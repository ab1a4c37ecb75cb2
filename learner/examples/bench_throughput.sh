#!/usr/bin/env bash
# Env steps per second at 512 envs including updates, the Rust and the Python learner one after
# the other on the same recipe file: quad_flat with its stop rule cut to ITERATIONS (default 10)
# and no milestone check, each learner starting its own local server (target/release).
#   cargo build --release -p unigait-server -p unigait-learner
#   learner/examples/bench_throughput.sh [OUT_DIR]      (default /tmp/unigait-bench-throughput)
# Prints the median env_steps_per_s of iterations 2..N of each progress.csv, and the wall time.
# LEARNERS (default "rust python") picks which run; RUST_BIN the learner binary to time; ENGINE
# (default: the recipe's, rapier) the physics engine of the sessions, "rapier" or "articulated".
set -euo pipefail
cd "$(dirname "$0")/../.."
out="${1:-/tmp/unigait-bench-throughput}"
iterations="${ITERATIONS:-10}"
learners="${LEARNERS:-rust python}"
rust_bin="${RUST_BIN:-target/release/unigait-learner}"
rm -rf "$out"
mkdir -p "$out"
recipe="$out/quad_flat_bench.toml"
# The shipped recipe, its stop rule shortened, its milestone check dropped, its engine ENGINE.
engine="${ENGINE:-rapier}"
sed -e "s/^iterations = .*/iterations = $iterations/" -e '/^milestone = "M1"$/d' \
    -e '/^check_every/d' -e "s/^engine = .*/engine = \"$engine\"/" \
    assets/recipes/quad_flat.toml >"$recipe"
grep -q "^engine = \"$engine\"" "$recipe"
export UNIGAIT_SERVER_BIN="$PWD/target/release/unigait-server"
median() {
    .venv/bin/python - "$1" <<'EOF'
import csv, statistics, sys
rows = list(csv.DictReader(open(sys.argv[1])))[1:]
v = [float(r["env_steps_per_s"]) for r in rows]
u = [float(r["time_share/update"]) for r in rows]
t = [float(r["iteration_time_s"]) for r in rows]
print(f"median env_steps_per_s {statistics.median(v):.0f} (min {min(v):.0f}, max {max(v):.0f}),"
      f" iteration {statistics.median(t):.2f} s, update share {statistics.median(u):.0%}")
EOF
}
for learner in $learners; do
    start=$(date +%s.%N)
    case "$learner" in
        rust) "$rust_bin" train --recipe "$recipe" --log-dir "$out/rust" >"$out/rust.log" 2>&1 ;;
        python) .venv/bin/unigait train --recipe "$recipe" --log-dir "$out/python" \
            >"$out/python.log" 2>&1 ;;
    esac
    end=$(date +%s.%N)
    csv=$(ls "$out/$learner"/01_*/progress.csv)
    printf '%-6s wall %.1f s, ' "$learner" "$(echo "$end - $start" | bc)"
    median "$csv"
done
