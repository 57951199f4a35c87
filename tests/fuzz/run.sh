#!/usr/bin/env bash
# Fuzz lensrt's file parsers (lens tables, phasor files, PSF bank indexes) with libFuzzer
# (clang), each target for SECONDS (default 15):
#   bash tests/fuzz/run.sh 20
# The library is built with clang into build/fuzz, static, instrumented with ASan, UBSan and
# libFuzzer's coverage (fuzzer-no-link); corpora and crash artifacts live under build/fuzz.
# Any crash, leak, timeout or sanitizer report stops the fuzzer and fails this script.
set -euo pipefail
seconds="${1:-15}"
root="$(cd "$(dirname "$0")/../.." && pwd)"
build="${LENSRT_FUZZ_BUILD:-$root/build/fuzz}" # another folder: LENSRT_FUZZ_BUILD
command -v clang >/dev/null || { echo "fuzz: clang is missing (scripts/setup-system.sh installs it)" >&2; exit 1; }

mkdir -p "$build"

# 1. Build the library (no GL, OpenMP, EXR or tests: the parsers only) and the targets
cmake -S "$root/tests/fuzz" -B "$build" -DCMAKE_C_COMPILER=clang -DCMAKE_BUILD_TYPE=Debug \
  -DBUILD_SHARED_LIBS=OFF -DLENSRT_WITH_GL=OFF -DLENSRT_WITH_OPENMP=OFF -DLENSRT_WITH_EXR=OFF \
  -DLENSRT_BUILD_TESTS=OFF -DLENSRT_SANITIZE=OFF \
  "-DCMAKE_C_FLAGS=-g -O1 -fno-omit-frame-pointer -fsanitize=address,undefined,fuzzer-no-link -fno-sanitize-recover=all" \
  >"$build/configure.log" 2>&1 || { cat "$build/configure.log" >&2; exit 1; }
cmake --build "$build" -j 2 --target fuzz_table fuzz_phasors fuzz_bank fuzz_seed >/dev/null

# 2. Seed corpora: the shipped tables, and phasor files saved by the fuzz render itself
mkdir -p "$build/corpus/table" "$build/corpus/phasors" "$build/corpus/bank" "$build/artifacts"
for t in "$root"/generated/*/lens*.table "$root"/generated/0001-angenieux-double-gauss/scene-fits/demo/*.table; do
  cp "$t" "$build/corpus/table/$(echo "${t#"$root"/generated/}" | tr / _)"
done
# ... and small hand-made tables (a ghost table with its ghost lines and P_clip, issue 13)
cp "$root"/tests/fuzz/seeds/table/*.table "$build/corpus/table/"
# ... PSF bank indexes (issue 23): a tiny hand-made one naming fuzz_bank's node files
cp "$root"/tests/fuzz/seeds/bank/*.index "$build/corpus/bank/"
ASAN_OPTIONS=detect_leaks=1 "$build/fuzz_seed" "$build/corpus/phasors/run.phasors" "$build/corpus/phasors/empty.phasors"

# 3. Known crashers stay fixed: every input in tests/fuzz/regressions/<target>/ runs once
export UBSAN_OPTIONS=halt_on_error=1:print_stacktrace=1
export ASAN_OPTIONS=detect_leaks=1
for target in table phasors bank; do
  reg="$root/tests/fuzz/regressions/$target"
  if [ -d "$reg" ] && [ -n "$(ls -A "$reg")" ]; then
    "$build/fuzz_$target" -runs=0 "$reg"/* >"$build/regressions-$target.log" 2>&1 \
      || { cat "$build/regressions-$target.log" >&2; echo "fuzz: regression input of $target fails" >&2; exit 1; }
  fi
done

# 4. Fuzz each target for SECONDS; libFuzzer exits non-zero on any finding. An input's
# timeout is 60 s: the shipped tables' tiny renders take up to 10 s each under ASan and
# coverage on one idle core (0004's window basis, 135 slots), and CI's noisy machines
# have made that 11 s; a hang runs forever, so 60 s still finds one
for target in table phasors bank; do
  echo "fuzz: $target for ${seconds}s" >&2
  dict=()
  if [ -f "$root/tests/fuzz/$target.dict" ]; then dict=("-dict=$root/tests/fuzz/$target.dict"); fi
  if ! "$build/fuzz_$target" "${dict[@]}" -max_total_time="$seconds" -rss_limit_mb=2048 -timeout=60 \
       -max_len=2097152 -artifact_prefix="$build/artifacts/$target-" -print_final_stats=1 \
       "$build/corpus/$target" >"$build/$target.log" 2>&1; then
    tail -n 60 "$build/$target.log" >&2
    echo "fuzz: $target FAILED (artifacts in $build/artifacts, log $build/$target.log)" >&2
    exit 1
  fi
  grep -E "^stat::(number_of_executed_units|average_exec_per_sec|peak_rss_mb)" "$build/$target.log" | sed "s/^/fuzz: $target /" >&2
done
echo "fuzz: OK" >&2
