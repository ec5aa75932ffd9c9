#!/usr/bin/env bash
# Generates every rig simulator scenario (config/scenarios/*.yaml) as a bag, offline and
# deterministically (seeded; no roscore, no wall clock):
#
#   bags/generate_bags.sh [OUTDIR] [SCENARIO ...]
#
#   OUTDIR     output folder (default bags/generated/, git-ignored); one <scenario>.bag each
#   SCENARIO   scenario names to make (default: all of config/scenarios/)
#
# Environment: JOBS (parallel scenarios, default 2), COMPRESSION (none|lz4|bz2, default lz4),
#              MAX_FRAMES (cut every run to its first N camera frames; for quick checks).
# Needs the workspace built (./catkin_ws_setup.sh); finds make_scenario_bag through rosrun.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export PATH="/usr/bin:/bin:$PATH"
OUT="${1:-$ROOT/bags/generated}"
shift || true
JOBS="${JOBS:-2}"
COMPRESSION="${COMPRESSION:-lz4}"
MAX_FRAMES="${MAX_FRAMES:-0}"

if [ -z "${ROS_PACKAGE_PATH:-}" ] || ! rospack find rig_drivers >/dev/null 2>&1; then
  set +u
  # shellcheck disable=SC1091
  source "$ROOT/devel/setup.bash"
  set -u
fi
TOOL="$(catkin_find --first-only rig_drivers make_scenario_bag 2>/dev/null || true)"
if [ -z "$TOOL" ] || [ ! -x "$TOOL" ]; then
  echo "generate_bags.sh: make_scenario_bag not built; run ./catkin_ws_setup.sh first" >&2
  exit 1
fi

mkdir -p "$OUT"
if [ "$#" -gt 0 ]; then
  scenarios=()
  for n in "$@"; do scenarios+=("$ROOT/config/scenarios/$n.yaml"); done
else
  scenarios=("$ROOT"/config/scenarios/*.yaml)
fi

start=$(date +%s.%N)
printf '%s\n' "${scenarios[@]}" |
  xargs -P "$JOBS" -I{} "$TOOL" --scenario {} --out-dir "$OUT" --compression "$COMPRESSION" \
    --max-frames "$MAX_FRAMES"
end=$(date +%s.%N)
awk -v a="$start" -v b="$end" -v n="${#scenarios[@]}" -v o="$OUT" \
  'BEGIN { printf "generate_bags.sh: %d scenario bags in %s (%.1f s wall)\n", n, o, b - a }'
