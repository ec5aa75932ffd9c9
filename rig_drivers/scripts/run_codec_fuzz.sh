#!/usr/bin/env bash
# Builds the rig codec libFuzzer target with clang++-14 (-fsanitize=fuzzer,address) and runs it
# for a bounded time, writing a JUnit XML result so catkin's run_tests counts it.
#   run_codec_fuzz.sh <result.xml> [seconds=20] [workdir=/tmp/rig_codec_fuzz]
# A missing clang, a build failure or any crash/sanitizer finding is a failed test case.
set -u
XML=${1:?usage: run_codec_fuzz.sh <result.xml> [seconds] [workdir]}
SECS=${2:-20}
WORK=${3:-/tmp/rig_codec_fuzz}
HERE=$(cd "$(dirname "$0")/.." && pwd)   # rig_drivers
mkdir -p "$WORK" "$(dirname "$XML")"
LOG="$WORK/fuzz.log"
: >"$LOG"

xml_escape() { sed -e 's/&/\&amp;/g' -e 's/</\&lt;/g' -e 's/>/\&gt;/g' -e 's/"/\&quot;/g' | tr -cd '\11\12\15\40-\176'; }

write_result() {  # $1 = pass|fail, $2 = message
  local t_end elapsed
  t_end=$(date +%s)
  elapsed=$((t_end - T0))
  {
    echo '<?xml version="1.0" encoding="UTF-8"?>'
    echo "<testsuite name=\"rig_codec_fuzz\" tests=\"1\" failures=\"$([ "$1" = pass ] && echo 0 || echo 1)\" errors=\"0\" time=\"$elapsed\">"
    echo "  <testcase classname=\"rig_drivers.fuzz\" name=\"codec_libfuzzer_${SECS}s\" time=\"$elapsed\">"
    if [ "$1" != pass ]; then
      echo "    <failure message=\"$(printf '%s' "$2" | xml_escape)\"><![CDATA["
      tail -n 60 "$LOG" | tr -cd '\11\12\15\40-\176' | sed 's/]]>/]] >/g'
      echo "]]></failure>"
    fi
    echo "    <system-out><![CDATA[$(printf '%s' "$2" | sed 's/]]>/]] >/g')]]></system-out>"
    echo "  </testcase>"
    echo "</testsuite>"
  } >"$XML"
  echo "rig codec fuzz: $1 - $2"
  [ "$1" = pass ]
  exit $?
}

T0=$(date +%s)
CXX=${RIG_FUZZ_CXX:-$(command -v clang++-14 || command -v clang++ || true)}
if [ -z "$CXX" ] || ! [ -x "$(command -v "$CXX")" ]; then
  write_result fail "clang++-14 not found: install clang-14 libclang-rt-14-dev (catkin_ws_setup.sh)"
fi
BIN="$WORK/fuzz_codec"
if ! "$CXX" -std=c++17 -O1 -g -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined \
    -I"$HERE/include" "$HERE/test/protocol/fuzz_codec.cpp" "$HERE/src/protocol/codec.cpp" \
    "$HERE/src/protocol/firmware.cpp" "$HERE/src/protocol/track_drv.cpp" \
    "$HERE/src/protocol/car_drv.cpp" "$HERE/src/protocol/truck_drv.cpp" \
    -o "$BIN" >>"$LOG" 2>&1; then
  write_result fail "fuzzer build failed with $CXX"
fi
CORPUS="$WORK/corpus"
mkdir -p "$CORPUS"
# Seeds: valid frames (first byte = chunk size) so the fuzzer starts from the real format.
/usr/bin/python3 - "$CORPUS" <<'PY' >>"$LOG" 2>&1 || true
import binascii, struct, sys, os
def frame(board, mid, seq, payload=b""):
    body = struct.pack("<BBBBI", len(payload), 1, board, mid, seq) + payload
    return b"\xa5\x5a" + body + struct.pack("<H", binascii.crc_hqx(body, 0xFFFF))
seeds = {
    "mode": frame(1, 0x02, 7, b"\x02"),
    "init": frame(1, 0x01, 8),
    "track_state": frame(1, 0x81, 9, bytes(range(18)) + b"\x01\x02"),
    "car_sensors": frame(2, 0x82, 10, bytes(20) + b"\x01"),
    "ack_and_garbage": b"\x00\xa5\xa5" + frame(1, 0x80, 11, struct.pack("<IBB", 3, 0x10, 1)) + b"\x5a",
}
for name, data in seeds.items():
    open(os.path.join(sys.argv[1], "seed_" + name), "wb").write(b"\x05" + data)
# structured seeds (first byte bit 7): records [id, length, payload] encoded with valid CRCs
def rec(mid, payload=b""):
    return bytes([mid, len(payload)]) + payload
session = (rec(0x02, b"\x02") + rec(0x01) + rec(0x10, struct.pack("<iBHH", 500000, 0, 200, 400)) +
           rec(0x04) + rec(0x10, struct.pack("<iBHH", 10000, 1, 0, 0)) + rec(0x11, struct.pack("<hhB", 1500, -700, 0)) +
           rec(0x12, struct.pack("<I", 1234)) + rec(0x13, struct.pack("<I", 40)) + rec(0x07) + rec(0x08) +
           rec(0x05) + rec(0x03) + rec(0x06))
open(os.path.join(sys.argv[1], "seed_structured"), "wb").write(b"\x83" + session)
open(os.path.join(sys.argv[1], "seed_structured_garbage"), "wb").write(b"\xc7" + session)
PY
if "$BIN" -max_total_time="$SECS" -timeout=5 -rss_limit_mb=1024 -max_len=512 \
    -artifact_prefix="$WORK/" "$CORPUS" >>"$LOG" 2>&1; then
  RUNS=$(grep -o 'Done [0-9]* runs' "$LOG" | tail -1)
  write_result pass "no crash in ${SECS}s (${RUNS:-runs unknown}) with $CXX"
else
  write_result fail "fuzzer found a failing input (artifact in $WORK), see log"
fi
