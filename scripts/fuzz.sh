#!/usr/bin/env bash
# The fuzzing suite (fuzz/): build every cargo-fuzz target once, then run each for
# SECONDS_PER_TARGET seconds (default 60) from its committed seeds, with a memory limit (an
# allocation bomb is a crash) and a per-input timeout (a hang is a crash). Exits non-zero if any
# target crashed, printing each crashing input's path.
#
#   bash scripts/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]
#
# Environment: FUZZ_RSS_LIMIT_MB (2048), FUZZ_TIMEOUT_S (10, per input).
#
# Toolchain: cargo-fuzz's default build adds AddressSanitizer (-Zsanitizer=address), a flag
# only a nightly rustc accepts, and CI has the stable toolchain alone. `-s none` drops the
# sanitizer; everything else cargo-fuzz passes (the SanitizerCoverage pass and its LLVM
# options, `--cfg fuzzing`, debug assertions) is accepted by stable rustc, so neither nightly
# nor RUSTC_BOOTSTRAP is needed. The readers are safe Rust, where ASan would add little:
# panics, overflow checks (debug assertions are on), timeouts and the memory limit are what
# catch their bugs.
#
# Files, all git-ignored under fuzz/: fuzz/target (the build), fuzz/corpus/<target> (the
# working corpus: the seeds of fuzz/seeds/<target> are copied in, and what the fuzzer adds is
# kept for the next local run), fuzz/artifacts/<target> (crashing inputs), fuzz/scratch (logs
# and temporary files). Nothing is written into the committed seeds.
set -euo pipefail
cd "$(dirname "$0")/.."

SECONDS_PER_TARGET=${1:-60}
shift || true
RSS_LIMIT_MB=${FUZZ_RSS_LIMIT_MB:-2048}
TIMEOUT_S=${FUZZ_TIMEOUT_S:-10}
if [ $# -gt 0 ]; then
  TARGETS=("$@")
else
  TARGETS=(config obj ply envmap transfer btf form form_check npz config_set shard_manifest record_paths)
fi

if ! cargo fuzz --version >/dev/null 2>&1; then
  echo "fuzz: installing cargo-fuzz"
  cargo install cargo-fuzz --locked
fi

start=$(date +%s)
cargo fuzz build -s none
echo "fuzz: built in $(($(date +%s) - start)) s"

host=$(rustc -vV | sed -n 's/^host: //p')
bin_dir=fuzz/target/$host/release
scratch=fuzz/scratch
mkdir -p "$scratch/tmp"
# The env-map target writes each input to a temporary file: keep those under fuzz/.
export TMPDIR=$PWD/$scratch/tmp

failed=()
for t in "${TARGETS[@]}"; do
  corpus=fuzz/corpus/$t
  artifacts=fuzz/artifacts/$t
  log=$scratch/$t.log
  mkdir -p "$corpus" "$artifacts"
  cp fuzz/seeds/"$t"/* "$corpus"/
  before=$(ls "$artifacts" | wc -l)
  echo "fuzz: $t for ${SECONDS_PER_TARGET} s (log: $log)"
  rc=0
  # libFuzzer stops itself after -max_total_time; the outer timeout is a backstop for a
  # hang libFuzzer's own -timeout does not catch.
  timeout $((SECONDS_PER_TARGET + 120)) "$bin_dir/$t" "$corpus" \
    -max_total_time="$SECONDS_PER_TARGET" -rss_limit_mb="$RSS_LIMIT_MB" -timeout="$TIMEOUT_S" \
    -artifact_prefix="$artifacts/" -print_final_stats=1 >"$log" 2>&1 || rc=$?
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log")
  echo "fuzz: $t: exit $rc, ${execs:-?} executions, corpus $(ls "$corpus" | wc -l) files"
  if [ "$rc" -ne 0 ] || [ "$(ls "$artifacts" | wc -l)" -ne "$before" ]; then
    grep -E "^(==[0-9]+== ERROR|thread '.*' panicked|.*panicked at)" "$log" | head -3 || true
    tail -n 30 "$log" | grep -E "Test unit written to|^artifact_prefix" || true
    failed+=("$t")
  fi
done
rm -rf "$scratch/tmp"
echo "fuzz: done in $(($(date +%s) - start)) s"

if [ ${#failed[@]} -gt 0 ]; then
  echo "fuzz: crashes in: ${failed[*]}; crashing inputs (replay with $bin_dir/<target> FILE):"
  for t in "${failed[@]}"; do
    ls -1 fuzz/artifacts/"$t"/* 2>/dev/null | sed 's/^/  /'
  done
  exit 1
fi
