#!/usr/bin/env bash
# The evaluator's caps kernels' and the sides' fill's static throughput
# (llvm-mca), for a host whose guest hides the hardware counters. Builds svpack with v0 symbol
# mangling into target/mca (about two minutes the first time), then runs
# benches/kernel_mca.py on it. MCPU=CPU (any CPU llvm-mca knows, such as
# znver3) models another CPU; default icelake-server.
set -euo pipefail
cd "$(dirname "$0")/.."
for tool in llvm-mca objdump nm; do
  command -v "$tool" >/dev/null || { echo "$tool not found (Debian: apt-get install llvm binutils)" >&2; exit 1; }
done
RUSTFLAGS="-C symbol-mangling-version=v0" CARGO_TARGET_DIR=target/mca \
  cargo build --release --quiet --bin svpack
python3 benches/kernel_mca.py target/mca/release/svpack "${MCPU:-icelake-server}"
