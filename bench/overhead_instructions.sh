#!/usr/bin/env bash
# Filter overhead ratio PF step / (N x one model step) in executed instructions (callgrind),
# which other jobs on the machine cannot disturb. Counts only the stepping of one criterion
# window (tests/examples/pf_overhead.rs); valve at N = 512, reaction wheel at N = 128.
# Needs valgrind. About a minute.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
cargo build --quiet --release -p prognos-tests --example pf_overhead
bin="${CARGO_TARGET_DIR:-$root/target}/release/examples/pf_overhead"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
count() {
    valgrind --tool=callgrind --callgrind-out-file="$tmp/out" \
        --toggle-collect='*counted_window*' "$bin" "$1" "$2" 2>&1 |
        sed -n 's/.*Collected : \([0-9]*\).*/\1/p'
}
printf '%-6s %16s %16s %16s %8s %8s\n' model "PF step" "model steps" "model+lik." ratio "ratio+lik"
for system in valve wheel; do
    pf=$(count "$system" pf)
    model=$(count "$system" model)
    model_ll=$(count "$system" model_ll)
    awk -v s="$system" -v a="$pf" -v b="$model" -v c="$model_ll" \
        'BEGIN { printf "%-6s %16d %16d %16d %8.3f %8.3f\n", s, a, b, c, a / b, a / c }'
done
