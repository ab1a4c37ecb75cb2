#!/usr/bin/env bash
# The learner update side by side: torch (tests/data/bench_update.py, paper dims) and the Rust
# libraries (examples/bench_update.rs), 1 and 2 threads, one after another in one run.
#   cargo build --release -p unigait-learner --features bench-candle --example bench_update
#   learner/examples/bench_side_by_side.sh [LIB...]   (default: burn; candle needs bench-candle)
# REPEATS (default 3) updates each after one warm-up, ENVS (default 512).
set -euo pipefail
cd "$(dirname "$0")/../.."
libs=("${@:-burn}")
repeats="${REPEATS:-3}"
envs="${ENVS:-512}"
OMP_NUM_THREADS=2 .venv/bin/python tests/data/bench_update.py --envs "$envs" --paper-dims \
    --threads 1 2 --variants after --repeats "$repeats"
for lib in "${libs[@]}"; do
    for t in 1 2; do
        RAYON_NUM_THREADS=$t target/release/examples/bench_update --lib "$lib" --envs "$envs" \
            --repeats "$repeats"
    done
done
