#!/usr/bin/env bash
# Builds the libFuzzer targets (clang, ASan + UBSan: the CMake preset "asan",
# whose build scripts/sanitize.sh asan tests too) and runs them (fuzz/README.md):
#   fuzz/run.sh replay [SECONDS]         every target over its seeds and regression
#                                        cases, then SECONDS (default 10) of fuzzing
#                                        each, two targets at a time: what CI runs
#   fuzz/run.sh campaign SECONDS [TARGET...]
#                                        fuzz each target for SECONDS or 10^6 runs,
#                                        whichever comes first, two at a time; the
#                                        corpora grow in build-asan/fuzzing/corpus, findings
#                                        land in build-asan/fuzzing/artifacts
# Seeds come from ../shared/data and from tile sets built here (make_seeds.py);
# only small hand-written seeds and regression cases are in the repository.
# The sets are built by the ASan build's own surfcast-build.
set -euo pipefail
cd "$(dirname "$0")/.."
mode="${1:?usage: fuzz/run.sh replay [SECONDS] | campaign SECONDS [TARGET...]}"
shift

scripts/setup.sh --no-build --clang
build=build-asan
cmake --preset asan >/dev/null
cmake --build "$build" --target fuzz_all surfcast-build
scripts/test-venv.sh

data="${SURFCAST_DATA_DIR:-../shared/data}"
if [ ! -f "$data/PROVENANCE.md" ]; then
  echo "fuzz/run.sh: no scans at $data (../shared/data); the reader seeds come from them" >&2
  exit 1
fi
work="$build/fuzzing"
rm -rf "$work/sets" "$work/seeds"
mkdir -p "$work/sets" "$work/seeds" "$work/corpus" "$work/artifacts"
"$build/bin/surfcast-build" -q --default-scene --scene-points 3000 -o "$work/sets/s" >/dev/null
"$build/bin/surfcast-build" -q --default-scene --scene-points 3000 --weights analytic -o "$work/sets/weighted" >/dev/null
if ! "$build/bin/surfcast-build" -q "$data/autzen_trim.las" --attributes all --capacity 20000 -o "$work/sets/autzen" \
     > "$work/autzen.log" 2>&1; then
  tail -n 40 "$work/autzen.log" >&2
  echo "fuzz/run.sh: building the autzen seed set failed (log $work/autzen.log)" >&2
  exit 1
fi
build/test-venv/bin/python fuzz/make_seeds.py "$data" "$work/sets" "$work/seeds"
export SURFCAST_FUZZ_SETS="$PWD/$work/sets"

targets=(read_ply read_las read_laz read_e57 read_pcd read_xyz read_obj read_gltf read_glb tileset block range http_request client_response s3_xml)
corpora() {  # the seed folders a target reads, existing ones only
  for d in "$work/seeds/$1" "fuzz/seeds/$1" "fuzz/regressions/$1"; do [ -d "$d" ] && echo "$d"; done
}
flags=(-rss_limit_mb=2048 -timeout=20 -max_len=65536)

replay_one() {  # one target over its seeds and regression cases, then $2 s of fuzzing
  local t="$1" seconds="$2" log="$work/artifacts/$1.log" dirs
  mapfile -t dirs < <(corpora "$t")
  mkdir -p "$work/corpus/$t" "$work/artifacts/$t"
  if ! "$build/fuzz/fuzz_$t" "${flags[@]}" -runs=0 "${dirs[@]}" > "$log" 2>&1 ||
     ! "$build/fuzz/fuzz_$t" "${flags[@]}" -max_total_time="$seconds" -artifact_prefix="$work/artifacts/$t/" \
       "$work/corpus/$t" "${dirs[@]}" >> "$log" 2>&1; then
    tail -n 40 "$log" >&2
    echo "fuzz/run.sh: $t failed (log $log, input in $work/artifacts/$t/)" >&2
    return 1
  fi
  echo "== $t (${dirs[*]}): $(grep -E '^Done' "$log" | tr '\n' ' ')"
}

if [ "$mode" = replay ]; then
  # Two targets at a time (each fuzzer is one process on one core). `unwaited`
  # counts jobs whose status has not been collected, finished or not, so that
  # every job's status is read by one `wait -n`.
  seconds="${1:-10}"
  failed=0
  unwaited=0
  trap 'kill $(jobs -p) 2>/dev/null || true' EXIT
  for t in "${targets[@]}"; do
    if ((unwaited >= 2)); then wait -n || failed=1; unwaited=$((unwaited - 1)); fi
    replay_one "$t" "$seconds" &
    unwaited=$((unwaited + 1))
  done
  while ((unwaited > 0)); do wait -n || failed=1; unwaited=$((unwaited - 1)); done
  exit "$failed"
fi

[ "$mode" = campaign ] || { echo "fuzz/run.sh: unknown mode $mode" >&2; exit 2; }
seconds="${1:?campaign SECONDS}"
shift
(($#)) && targets=("$@")
run_one() {
  local t="$1"
  mapfile -t dirs < <(corpora "$t")
  mkdir -p "$work/corpus/$t" "$work/artifacts/$t"
  "$build/fuzz/fuzz_$t" "${flags[@]}" -max_total_time="$seconds" -runs=1000000 -print_final_stats=1 \
    -artifact_prefix="$work/artifacts/$t/" "$work/corpus/$t" "${dirs[@]}" > "$work/artifacts/$t.log" 2>&1
  echo "== $t: exit $? $(grep -E '^stat::number_of_executed_units|^#[0-9]+ +DONE' "$work/artifacts/$t.log" | tr '\n' ' ')"
}
for ((i = 0; i < ${#targets[@]}; i += 2)); do
  run_one "${targets[i]}" &
  if ((i + 1 < ${#targets[@]})); then run_one "${targets[i + 1]}" & fi
  wait
done
