#!/usr/bin/env bash
# Firmware on QEMU: builds both firmware binaries (plain-text and defmt logging), runs them on
# the emulated Cortex-M4F (mps2-an386, `-icount shift=0`), runs the same scenarios on the host
# in f64, and fails if a run fails, if a firmware RUL differs from the host f64 RUL by more
# than 2 %, or if a budget is exceeded:
#   reaction wheel: worst instructions per 20 Hz sample <= 840,000 (N = 128 particles)
#   scooter:        worst instructions per 50 Hz sample <= 336,000
#   each image:     static RAM (data + bss) <= 64 KiB, stack high-water <= 8 KiB,
#                   flash (vectors + text + rodata + data) <= 256 KiB
# The plain-text build is the one parsed; the defmt build is built, sized and run for its exit
# status only (decoding needs `cargo install defmt-print`, about 3 minutes: see README).
set -euo pipefail
cd "$(dirname "$0")"
FW_DIR=$(pwd)
ROOT=$(cd .. && pwd)
export CARGO_TERM_COLOR=never

if ! command -v qemu-system-arm >/dev/null 2>&1; then
    apt-get update
    apt-get install -y --no-install-recommends qemu-system-arm
fi
rustup target add thumbv7em-none-eabihf
rustup component add llvm-tools
LLVM_SIZE=$(ls "$(rustc --print sysroot)"/lib/rustlib/*/bin/llvm-size | head -n 1)

echo "--- building the firmware (plain text and defmt)"
cargo build --release --locked --no-default-features --features plain --target-dir target/plain
cargo build --release --locked --target-dir target/defmt
ELF_DIR=target/plain/thumbv7em-none-eabihf/release
DEFMT_DIR=target/defmt/thumbv7em-none-eabihf/release

echo "--- host f64 reference runs of the same scenarios"
HOST_LOG=$(mktemp)
(cd "$ROOT" && cargo test --locked -p prognos-tests --test firmware_scenario -- --nocapture) | tee "$HOST_LOG"

QEMU=(qemu-system-arm -cpu cortex-m4 -machine mps2-an386 -nographic -monitor none -serial none
    -semihosting-config enable=on,target=native -icount shift=0 -kernel)
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }
# value KEY FILE: the last whole-word KEY=value in FILE.
value() { grep -oE "(^| )$1=[^ ]*" "$2" | tail -n 1 | cut -d= -f2; }
# check NAME MEASURED LIMIT: MEASURED <= LIMIT.
check() {
    if awk -v m="$2" -v l="$3" 'BEGIN { exit !(m != "" && m + 0 <= l + 0) }'; then
        echo "ok   $1 = $2 (limit $3)"
    else
        fail "$1 = ${2:-missing} exceeds $3"
    fi
}
# rul_check NAME FIRMWARE HOST: |FIRMWARE - HOST| / HOST <= 2 %.
rul_check() {
    local gap
    gap=$(awk -v f="$2" -v h="$3" 'BEGIN { if (f == "" || h == "" || h + 0 == 0) print "nan"; else { d = (f - h) / h; if (d < 0) d = -d; printf "%.3f", 100 * d } }')
    if [ "$gap" != nan ] && awk -v g="$gap" 'BEGIN { exit !(g <= 2.0) }'; then
        echo "ok   $1: firmware f32 $2 s, host f64 $3 s, gap $gap % (limit 2 %)"
    else
        fail "$1: firmware f32 ${2:-missing} s, host f64 ${3:-missing} s, gap $gap % (limit 2 %)"
    fi
}
sizes() {
    local elf=$1 label=$2 flash ram
    flash=$("$LLVM_SIZE" -A "$elf" | awk '$1 ~ /^\.(vector_table|text|rodata|data)$/ { s += $2 } END { print s + 0 }')
    ram=$("$LLVM_SIZE" -A "$elf" | awk '$1 ~ /^\.(data|bss|uninit)$/ { s += $2 } END { print s + 0 }')
    check "$label flash bytes" "$flash" 262144
    check "$label static RAM bytes" "$ram" 65536
}

for bin in reaction_wheel scooter; do
    echo "--- $bin on QEMU mps2-an386"
    log=$(mktemp)
    start=$(date +%s)
    if timeout 300 "${QEMU[@]}" "$ELF_DIR/$bin" | tee "$log"; then
        echo "ok   $bin exited with status 0 ($(( $(date +%s) - start )) s)"
    else
        fail "$bin run failed (status $?)"
    fi
    grep -q "result=pass" "$log" || fail "$bin did not report result=pass"
    sizes "$ELF_DIR/$bin" "$bin (plain)"
    sizes "$DEFMT_DIR/$bin" "$bin (defmt)"
    check "$bin stack high-water bytes (per-sample loop)" "$(value stack_high_water_bytes "$log")" 8192
    check "$bin stack high-water bytes (start-up)" "$(value init_stack_high_water_bytes "$log")" 8192
    if [ "$bin" = reaction_wheel ]; then
        check "$bin worst instructions per sample" "$(value step_worst_instructions "$log")" 840000
        check "$bin stack high-water bytes (RUL prediction)" "$(value rul_stack_high_water_bytes "$log")" 8192
        rul_check "$bin RUL" "$(value rul_s "$log")" \
            "$(grep 'firmware-reference wheel' "$HOST_LOG" | grep -o ' rul_s=[^ ]*' | cut -d= -f2)"
    else
        check "$bin worst instructions per sample" "$(value step_worst_instructions "$log")" 336000
        rul_check "$bin RUL (usage 1)" "$(value rul_usage1_s "$log")" \
            "$(grep 'firmware-reference scooter' "$HOST_LOG" | grep -o ' rul_usage1_s=[^ ]*' | cut -d= -f2)"
        rul_check "$bin RUL (after reactivation)" "$(value rul_s "$log")" \
            "$(grep 'firmware-reference scooter' "$HOST_LOG" | grep -o ' rul_s=[^ ]*' | cut -d= -f2)"
    fi
    # The defmt build must run to a passing exit too (its frames are not decoded here).
    if timeout 300 "${QEMU[@]}" "$DEFMT_DIR/$bin" >/dev/null; then
        echo "ok   $bin (defmt) exited with status 0"
    else
        fail "$bin (defmt) run failed"
    fi
    rm -f "$log"
done
rm -f "$HOST_LOG"

if [ "$failures" -ne 0 ]; then
    echo "firmware on QEMU: $failures check(s) failed"
    exit 1
fi
echo "firmware on QEMU: all checks passed"
