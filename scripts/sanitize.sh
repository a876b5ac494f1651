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
scripts/setup.sh --no-build
cmake --preset "$preset"
cmake --build "build-$preset" --parallel
if [ ! -x "build-$preset/test-venv/bin/python" ]; then
  python3 -m venv "build-$preset/test-venv"
fi
"build-$preset/test-venv/bin/pip" install -q -r tests/requirements.txt

export UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
export ASAN_OPTIONS=detect_leaks=1:strict_string_checks=1
export TSAN_OPTIONS="halt_on_error=1 second_deadlock_stack=1 suppressions=$PWD/.ci/tsan.supp"
# (Mesa's lavapipe stays loaded in ASan builds: client/gpu/context.cpp says why.)
ctest --test-dir "build-$preset" --output-on-failure --timeout 3600 "$@"
