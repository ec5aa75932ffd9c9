#!/usr/bin/env bash
# The main job: replays the rendered RT3 run (ServoTrack, 25 s, 750 frames, L515 noise) through the
# tracking graph headless (launch/replay.launch, replay mode, a private roscore) and prints the
# evaluator's table and summary: frames, tracked, dropped, ATE and max errors against the bag's
# ground truth, ms per frame, and where the trajectory and the map were saved.
#
#   bags/replay_demo.sh [BAG]        default bags/generated/RT3.bag, generated first if missing
#
# Environment: RATE (playback rate, default 1), OUT (folder of the saved files, default
# /tmp/depth_track_demo). Needs the workspace built (./catkin_ws_setup.sh).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export PATH="/usr/bin:/bin:$PATH"
BAG="${1:-$ROOT/bags/generated/RT3.bag}"
RATE="${RATE:-1}"
OUT="${OUT:-/tmp/depth_track_demo}"
set +u
# shellcheck disable=SC1091
source "$ROOT/devel/setup.bash"
set -u
if [ ! -f "$BAG" ]; then
  if [ "$BAG" != "$ROOT/bags/generated/RT3.bag" ]; then
    echo "replay_demo.sh: no bag $BAG" >&2
    exit 1
  fi
  echo "== generating $BAG (make_scenario_bag, seconds)"
  "$ROOT/bags/generate_bags.sh" "$ROOT/bags/generated" RT3
fi
mkdir -p "$OUT"
# A master of our own on a free port: never a stray roscore's parameters, never its clock.
PORT=$(/usr/bin/python3 -c 'import socket; s=socket.socket(); s.bind(("", 0)); print(s.getsockname()[1])')
export ROS_MASTER_URI="http://localhost:$PORT"
export ROS_HOME="$OUT/ros_home"
LOG="$OUT/replay.log"
echo "== replaying $BAG through the graph (rate $RATE, master $ROS_MASTER_URI, log $LOG)"
start=$(date +%s)
set +e
roslaunch -p "$PORT" "$ROOT/launch/replay.launch" bag:="$BAG" rate:="$RATE" \
  trajectory_path:="$OUT/trajectory.txt" map_path:="$OUT/map.bt" > "$LOG" 2>&1 &
LAUNCH=$!
set -e
wait $LAUNCH || true
end=$(date +%s)
if ! grep -q "^summary:" "$LOG"; then
  echo "replay_demo.sh: the evaluator printed no summary; the end of $LOG:" >&2
  tail -40 "$LOG" >&2
  exit 1
fi
sed -n '/^==== evaluator/,/^summary:/p' "$LOG"
echo "replay_demo.sh: $(( end - start )) s wall; trajectory (TUM, camera in odom / map): $OUT/trajectory.txt, $OUT/trajectory_map.txt; map (OctoMap): $OUT/map.bt"
