#!/usr/bin/env bash
# The test suite under a sanitizer build (CMakePresets.json), two tests at a time:
#   scripts/sanitize.sh asan [ctest args]   AddressSanitizer + UndefinedBehaviorSanitizer,
#                                            every test program (the build also holds
#                                            the libFuzzer targets fuzz/run.sh runs)
#   scripts/sanitize.sh tsan [ctest args]   ThreadSanitizer, the tests labelled
#                                            "threads" (tests/CMakeLists.txt)
# Any sanitizer report fails the test that triggered it (UBSan halts, ASan and
# LeakSanitizer exit non-zero). Builds into build-PRESET beside build/ (a
# folder configured by an older preset, e.g. with GCC, wants `cmake --preset
# PRESET --fresh`). Which heavy cases each sanitizer leaves to the release
# suite, and why: bench/RELIABILITY.md, "What each CI stage covers".
set -euo pipefail
cd "$(dirname "$0")/.."
preset="${1:?usage: scripts/sanitize.sh asan|tsan [ctest args]}"
shift
case "$preset" in
  asan) target=all select=() ;;
  tsan) target=threaded_tests select=(-L threads) ;;
  *) echo "usage: scripts/sanitize.sh asan|tsan [ctest args]" >&2; exit 2 ;;
esac
scripts/setup.sh --no-build --clang
cmake --preset "$preset"
cmake --build "build-$preset" --parallel --target "$target"
scripts/test-venv.sh

export UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
export ASAN_OPTIONS=detect_leaks=1:strict_string_checks=1
if [ "$preset" = tsan ]; then
  # TSan builds use clang and LLVM's OpenMP runtime, which loads its Archer
  # tool so that TSan sees OpenMP's barriers and reductions (GCC's libgomp
  # would show every parallel loop as a race). Accesses inside uninstrumented
  # libraries (Mesa's lavapipe, the Rust LAZ decoder) are not seen, and
  # ignore_noninstrumented_modules keeps their intercepted calls (malloc,
  # free) from being reported.
  export OMP_TOOL_LIBRARIES=/usr/lib/llvm-14/lib/libarcher.so
  export TSAN_OPTIONS="halt_on_error=1 second_deadlock_stack=1 ignore_noninstrumented_modules=1"
fi
# Two tests share the two cores: an OpenMP thread with nothing to do sleeps
# rather than spinning on the other test's core (LLVM's runtime, the sanitizer
# builds', spins 200 ms by default, GCC's a shorter while:
# bench/RELIABILITY.md, "CI stages").
export OMP_WAIT_POLICY="${OMP_WAIT_POLICY:-passive}"
# (Mesa's lavapipe stays loaded in ASan builds: client/gpu/context.cpp says why.)
ctest --test-dir "build-$preset" --output-on-failure --timeout 3600 -j "${CTEST_PARALLEL_LEVEL:-2}" "${select[@]}" "$@"
