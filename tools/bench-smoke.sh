#!/usr/bin/env bash
# Every benchmark still runs: the smallest sizes, and the MPI-capable ones also under
# mpiexec -n 2, so that the README's commands keep working. Tables go to a scratch
# folder; a failing benchmark's output is printed.
# Usage: tools/bench-smoke.sh PYTHON MPIEXEC
set -euo pipefail
# smoke sizes: the book's benchmark pages are not rewritten
export ADMM_BENCHMARK_PAGE=0
py=$1
mpiexec=$2
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
parallel=(acceleration acceleration_limit hertz_validation orderings penalty_cost polish_3d surface_metric)
# under mpiexec -n 2: the ones whose parallel paths differ from the serial ones (the
# surface metric, polishing, the r* sweeps); tests/ cover the rest under MPI
parallel_smoke=(acceleration hertz_validation polish_3d surface_metric)

run() {
  echo "== $*"
  if ! "$@" --out "$out" >"$out/log" 2>&1; then
    cat "$out/log"
    echo "benchmark failed: $*" >&2
    exit 1
  fi
}

for b in "${parallel[@]}" work_precision parallel_scaling; do run "$py" "benchmarks/$b.py" --quick; done
run "$py" benchmarks/hard_cases.py --small
run "$py" benchmarks/penalty_accuracy.py
run "$py" benchmarks/strips.py --quick
run "$py" benchmarks/polish_3d.py --scene hertz_sphere --quick
run "$py" benchmarks/contact_model.py --quick
run "$py" benchmarks/scale_3d.py --quick
run "$py" benchmarks/inner_tolerance.py --quick
run "$py" benchmarks/factor_prediction.py --quick
run "$py" benchmarks/step1_crossover.py --quick
run "$py" benchmarks/floating_3d.py --quick
run "$py" benchmarks/scale_2d.py --quick
run "$py" benchmarks/work_precision_adaptive.py --quick
run "$py" benchmarks/work_precision_adaptive.py --quick --part punch-step1
for b in "${parallel_smoke[@]}"; do run "$mpiexec" -n 2 "$py" "benchmarks/$b.py" --quick; done
echo "benchmarks: all ran"
