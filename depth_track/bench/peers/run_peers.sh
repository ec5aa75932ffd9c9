#!/usr/bin/env bash
# The peers side by side on the four inputs (TUM fr3/teddy, TUM fr1/xyz, rendered rt3 and
# xtest1_05_chair with L515 noise), then every trajectory re-scored by the independent checker
# shared/tools/eval_traj.py beside dt_peers' own ATE (our evaluation code).
#
#   depth_track/bench/peers/run_peers.sh [OUTDIR] [INPUT ...]     INPUT: teddy fr1_xyz rt3 xtest1
#
# Environment: DATA (default ../shared/data next to the checkout, else /work/shared/data),
#              FRAMES (cut each input to N frames), EXTRA (more dt_peers options).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)"
export PATH="/usr/bin:/bin:$PATH"
BIN="${DT_PEERS:-$ROOT/devel/lib/depth_track/dt_peers}"
OUT="${1:-/tmp/dt_peers}"
shift || true
INPUTS=("$@")
[ "${#INPUTS[@]}" -gt 0 ] || INPUTS=(teddy fr1_xyz rt3 xtest1)
DATA="${DATA:-$ROOT/../shared/data}"
[ -d "$DATA" ] || DATA=/work/shared/data
EVAL="${EVAL:-$(dirname "$DATA")/tools/eval_traj.py}"
FRAMES="${FRAMES:-0}"
if [ ! -x "$BIN" ]; then
  echo "run_peers.sh: $BIN not built (needs libopen3d-dev / libpcl-dev; ./catkin_ws_setup.sh)" >&2
  exit 1
fi
mkdir -p "$OUT"

for input in "${INPUTS[@]}"; do
  case "$input" in
    teddy) args=(--tum "$DATA/tum_fr3_teddy" --camera fr3); label=tum_fr3_teddy
      gt="$DATA/tum_fr3_teddy/groundtruth.txt" ;;
    fr1_xyz) args=(--tum "$DATA/tum_fr1_xyz" --camera fr1); label=tum_fr1_xyz
      gt="$DATA/tum_fr1_xyz/groundtruth.txt" ;;
    rt3) args=(--render rt3 --noise l515); label=rt3_l515; gt="$OUT/rt3_l515_gt.txt" ;;
    xtest1) args=(--render xtest1_05_chair --noise l515); label=xtest1_05_chair_l515
      gt="$OUT/xtest1_05_chair_l515_gt.txt" ;;
    *) echo "run_peers.sh: unknown input '$input' (teddy fr1_xyz rt3 xtest1)" >&2; exit 2 ;;
  esac
  echo "== $input"
  # shellcheck disable=SC2086
  "$BIN" "${args[@]}" --frames "$FRAMES" --out-dir "$OUT" ${EXTRA:-} | tee "$OUT/$label.log"
  echo "-- independent check ($EVAL): ATE from dt_peers vs eval_traj.py"
  for est in "$OUT/${label}"_*.txt; do
    [ "$est" = "$gt" ] && continue
    m="${est#"$OUT/${label}_"}"; m="${m%.txt}"
    ours=$(awk -v m="$m" '$1 == m && $2 ~ /^[0-9]+$/ {print $3}' "$OUT/$label.log")
    check=$(/usr/bin/python3 "$EVAL" "$est" "$gt")
    printf '  %-12s dt_peers ate_m=%s   eval_traj.py: %s\n' "$m" "$ours" "$check"
  done
done
