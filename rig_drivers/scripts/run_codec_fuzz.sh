#!/usr/bin/env bash
# Builds the two libFuzzer targets of the rig serial side with clang++-14 (ASan + UBSan) and runs
# each for a bounded time, writing one JUnit XML result (a test case per target) so catkin's
# run_tests counts them:
#   fuzz_codec     the codec alone (stream decoder against a reference scan, split feeds, frame
#                  and payload round trips); tens of thousands of inputs per second
#   fuzz_firmware  host commands, garbage and hardware inputs fed to TrackDRV, CarDRV and TruckDRV
#                  with bounded board time per input; protocol and physical invariants checked
# Sources: rig_drivers/test/protocol/fuzz_{codec,firmware}.cpp (input layouts and properties are
# described at their top). Seeds: rig_drivers/test/fuzz/corpus/{codec,firmware}, recorded frames of
# scenario bags (regenerate: rig_drivers/test/fuzz/make_corpus.py --generate).
#
#   run_codec_fuzz.sh <result.xml> [seconds=20] [workdir=/tmp/rig_fuzz]
#       CI use (./catkin_ws_setup.sh --test): both targets, `seconds` each. A missing clang, a build
#       failure or any finding (crash, sanitizer report, violated property) fails that test case;
#       the failure names the artifact and the command that replays it.
#   run_codec_fuzz.sh --build [workdir=/tmp/rig_fuzz]
#       only builds workdir/fuzz_codec and workdir/fuzz_firmware (for long runs).
# Environment: RIG_FUZZ_CXX (compiler, default clang++-14), RIG_FUZZ_TARGETS (default
# "codec firmware").
#
# Long runs (outside CI, at least one CPU-hour per target; 2 jobs in parallel, lowest priority):
#   S=$PWD/rig_drivers/test/fuzz/corpus W=/tmp/rig_fuzz
#   rig_drivers/scripts/run_codec_fuzz.sh --build $W && cd $W && mkdir -p long/codec long/firmware
#   nice -n 19 ./fuzz_codec -max_len=512 -timeout=5 -max_total_time=3600 -print_final_stats=1 \
#     -artifact_prefix=long/codec- long/codec $S/codec > long/codec.log 2>&1 &
#   nice -n 19 ./fuzz_firmware -max_len=1024 -timeout=10 -max_total_time=3600 -print_final_stats=1 \
#     -artifact_prefix=long/firmware- long/firmware $S/firmware > long/firmware.log 2>&1 &
# Progress: the "#N pulse/NEW ... cov: ft: corp: exec/s: rss:" lines of the logs; the last line
# of stats gives executions, exec/s and peak RSS. Replay a finding (with its property message and,
# for fuzz_firmware, a trace of what was sent and answered):
#   RIG_FUZZ_TRACE=1 ./fuzz_firmware long/firmware-crash-<sha1>
set -u
HERE=$(cd "$(dirname "$0")/.." && pwd)   # rig_drivers
SEEDS="$HERE/test/fuzz/corpus"
BUILD_ONLY=0
if [ "${1:-}" = "--build" ]; then
  BUILD_ONLY=1
  WORK=${2:-/tmp/rig_fuzz}
else
  XML=${1:?usage: run_codec_fuzz.sh <result.xml> [seconds] [workdir] | --build [workdir]}
  SECS=${2:-20}
  WORK=${3:-/tmp/rig_fuzz}
  mkdir -p "$(dirname "$XML")"
fi
TARGETS=${RIG_FUZZ_TARGETS:-codec firmware}
mkdir -p "$WORK"
T0=$(date +%s)

# Found by file name, so the sources may move between folders of src/.
src() {
  local f
  f=$(find "$HERE/src" -name "$1" -print -quit)
  [ -n "$f" ] || { echo "run_codec_fuzz.sh: $1 not found under $HERE/src" >&2; return 1; }
  echo "$f"
}

xml_escape() { sed -e 's/&/\&amp;/g' -e 's/</\&lt;/g' -e 's/>/\&gt;/g' -e 's/"/\&quot;/g' | tr -cd '\11\12\15\40-\176'; }

CASES=""
FAILURES=0
add_case() {  # $1 target, $2 pass|fail, $3 message, $4 log, $5 seconds taken
  local body=""
  if [ "$2" != pass ]; then
    FAILURES=$((FAILURES + 1))
    body="    <failure message=\"$(printf '%s' "$3" | xml_escape)\"><![CDATA[
$(tail -n 60 "$4" 2>/dev/null | tr -cd '\11\12\15\40-\176' | sed 's/]]>/]] >/g')
]]></failure>
"
  fi
  CASES="$CASES  <testcase classname=\"rig_drivers.fuzz\" name=\"$1_libfuzzer_${SECS:-0}s\" time=\"$5\">
$body    <system-out><![CDATA[$(printf '%s' "$3" | sed 's/]]>/]] >/g')]]></system-out>
  </testcase>
"
  echo "rig fuzz $1: $2 - $3"
}

write_result() {
  local n
  n=$(echo "$TARGETS" | wc -w)
  {
    echo '<?xml version="1.0" encoding="UTF-8"?>'
    echo "<testsuite name=\"rig_fuzz\" tests=\"$n\" failures=\"$FAILURES\" errors=\"0\" time=\"$(($(date +%s) - T0))\">"
    printf '%s' "$CASES"
    echo "</testsuite>"
  } >"$XML"
  [ "$FAILURES" = 0 ]
  exit $?
}

CXX=${RIG_FUZZ_CXX:-$(command -v clang++-14 || command -v clang++ || true)}
CXXFLAGS=(-std=c++17 -O1 -g -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined
          -I"$HERE/include")

# build <target>: compiles workdir/fuzz_<target>; the firmware harness itself is compiled without
# comparison tracing (its comparisons are the checks, not paths worth steering the fuzzer to).
build() {
  local t=$1 log="$WORK/build_$1.log" harness_flags=() sources=() s
  : >"$log"
  case $t in
    codec) for s in codec.cpp codec_host.cpp; do sources+=("$(src $s)") || return 1; done ;;
    firmware)
      harness_flags=(-fno-sanitize-coverage=trace-cmp)
      for s in codec.cpp codec_host.cpp firmware.cpp config_text.cpp track_drv.cpp car_drv.cpp \
               truck_drv.cpp; do
        sources+=("$(src $s)") || return 1
      done ;;
    *) echo "unknown fuzz target '$t' (codec, firmware)" >>"$log"; return 1 ;;
  esac
  "$CXX" "${CXXFLAGS[@]}" "${harness_flags[@]}" -c "$HERE/test/protocol/fuzz_$t.cpp" \
      -o "$WORK/fuzz_$t.o" >>"$log" 2>&1 &&
    "$CXX" "${CXXFLAGS[@]}" "${sources[@]}" "$WORK/fuzz_$t.o" -o "$WORK/fuzz_$t" >>"$log" 2>&1
}

for t in $TARGETS; do
  t_start=$(date +%s)
  log="$WORK/fuzz_$t.log"
  : >"$log"
  if [ -z "$CXX" ] || ! [ -x "$(command -v "$CXX")" ]; then
    [ "$BUILD_ONLY" = 1 ] && { echo "clang++-14 not found" >&2; exit 1; }
    add_case "$t" fail "clang++-14 not found: install clang-14 libclang-rt-14-dev (catkin_ws_setup.sh)" "$log" 0
    continue
  fi
  if ! build "$t"; then
    [ "$BUILD_ONLY" = 1 ] && { cat "$WORK/build_$t.log" >&2; exit 1; }
    add_case "$t" fail "fuzz_$t build failed with $CXX" "$WORK/build_$t.log" $(($(date +%s) - t_start))
    continue
  fi
  [ "$BUILD_ONLY" = 1 ] && { echo "built $WORK/fuzz_$t"; continue; }
  corpus="$WORK/corpus_$t"
  mkdir -p "$corpus"
  case $t in
    codec) opts=(-max_len=512 -timeout=5) ;;
    firmware) opts=(-max_len=1024 -timeout=10) ;;
  esac
  # New inputs go to the first folder (kept in workdir between runs); the seeds are only read.
  if "$WORK/fuzz_$t" "${opts[@]}" -max_total_time="$SECS" -rss_limit_mb=2048 -print_final_stats=1 \
      -artifact_prefix="$WORK/$t-" "$corpus" "$SEEDS/$t" >>"$log" 2>&1; then
    runs=$(grep -o 'Done [0-9]* runs' "$log" | tail -1)
    cov=$(grep -o 'cov: [0-9]* ft: [0-9]*' "$log" | tail -1)
    add_case "$t" pass "no finding in ${SECS}s (${runs:-runs unknown}, ${cov:-cov unknown}) with $CXX" \
      "$log" $(($(date +%s) - t_start))
  else
    artifact=$(grep -o "Test unit written to [^ ]*" "$log" | tail -1 | sed 's/Test unit written to //')
    why=$(grep -A1 -m1 'property violated' "$log" | tr -s ' \n' ' ')
    [ -n "$why" ] || why=$(grep -m1 -E 'ERROR: (AddressSanitizer|libFuzzer)|runtime error' "$log")
    add_case "$t" fail "fuzz_$t found a failing input: ${why:-see log}; replay: RIG_FUZZ_TRACE=1 $WORK/fuzz_$t ${artifact:-<artifact>}" \
      "$log" $(($(date +%s) - t_start))
  fi
done
[ "$BUILD_ONLY" = 1 ] && exit 0
write_result
