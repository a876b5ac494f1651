#!/usr/bin/env bash
# The whole test suite under a sanitizer build (CMakePresets.json):
#   scripts/sanitize.sh asan [ctest args]   AddressSanitizer + UndefinedBehaviorSanitizer
#   scripts/sanitize.sh tsan [ctest args]   ThreadSanitizer
# Any sanitizer report fails the test that triggered it (UBSan halts, ASan and
# LeakSanitizer exit non-zero). Builds into build-PRESET beside build/.
set -euo pipefail
cd "$(dirname "$0")/.."
preset="${1:?usage: scripts/sanitize.sh asan|tsan [ctest args]}"
shift
if [ "$preset" = tsan ]; then scripts/setup.sh --no-build --clang; else scripts/setup.sh --no-build; fi
cmake --preset "$preset"
cmake --build "build-$preset" --parallel
if [ ! -x "build-$preset/test-venv/bin/python" ]; then
  python3 -m venv "build-$preset/test-venv"
fi
"build-$preset/test-venv/bin/pip" install -q -r tests/requirements.txt

export UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
export ASAN_OPTIONS=detect_leaks=1:strict_string_checks=1
# TSan builds use clang and LLVM's OpenMP runtime, which loads its Archer tool
# so that TSan sees OpenMP's barriers and reductions (GCC's libgomp would show
# every parallel loop as a race). Accesses inside uninstrumented libraries
# (Mesa's lavapipe, the Rust LAZ decoder) are not seen, and
# ignore_noninstrumented_modules keeps their intercepted calls (malloc, free)
# from being reported.
export OMP_TOOL_LIBRARIES=/usr/lib/llvm-14/lib/libarcher.so
export TSAN_OPTIONS="halt_on_error=1 second_deadlock_stack=1 ignore_noninstrumented_modules=1"
# (Mesa's lavapipe stays loaded in ASan builds: client/gpu/context.cpp says why.)
ctest --test-dir "build-$preset" --output-on-failure --timeout 3600 "$@"
