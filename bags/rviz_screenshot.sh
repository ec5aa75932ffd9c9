#!/usr/bin/env bash
# A headless screenshot of a replay in rviz (config/rviz/tracking.rviz): the RT3 bag through the
# graph (launch/replay.launch rviz:=true, loop closure on, a private roscore) on a virtual X
# server (Xvfb, software OpenGL); once the bag's clock is AT seconds into the run and rviz had
# a moment to draw, the screen is grabbed with xwd and written as a small PNG.
#
#   bags/rviz_screenshot.sh [BAG] [PNG]     default bags/generated/RT3.bag (generated if missing),
#                                           docs/img/replay_rviz.png
#
# Environment: AT (s of the run to show, default 20), RATE (playback rate, default 0.5: rviz
# renders in software), OUT (folder of logs, default /tmp/depth_track_rviz).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export PATH="/usr/bin:/bin:$PATH"
BAG="${1:-$ROOT/bags/generated/RT3.bag}"
PNG="${2:-$ROOT/docs/img/replay_rviz.png}"
AT="${AT:-20}"
RATE="${RATE:-0.5}"
OUT="${OUT:-/tmp/depth_track_rviz}"
for tool in Xvfb xwd convert; do
  command -v "$tool" >/dev/null || {
    echo "rviz_screenshot.sh: $tool missing (Debian: xvfb, x11-apps, imagemagick)" >&2
    exit 1
  }
done
set +u
# shellcheck disable=SC1091
source "$ROOT/devel/setup.bash"
set -u
if [ ! -f "$BAG" ]; then
  [ "$BAG" = "$ROOT/bags/generated/RT3.bag" ] || { echo "rviz_screenshot.sh: no bag $BAG" >&2; exit 1; }
  "$ROOT/bags/generate_bags.sh" "$ROOT/bags/generated" RT3
fi
mkdir -p "$OUT" "$(dirname "$PNG")"

# A display nobody uses, and a master of our own.
DISP=99
while [ -e "/tmp/.X$DISP-lock" ] || [ -e "/tmp/.X11-unix/X$DISP" ]; do DISP=$((DISP + 1)); done
PORT=$(/usr/bin/python3 -c 'import socket; s=socket.socket(); s.bind(("", 0)); print(s.getsockname()[1])')
export ROS_MASTER_URI="http://localhost:$PORT" ROS_HOME="$OUT/ros_home"
export DISPLAY=":$DISP" LIBGL_ALWAYS_SOFTWARE=1

pids=()
cleanup() {
  # roslaunch starts the master and rosout in sessions of their own: it must be given the time
  # to stop them itself before anything is killed.
  for p in "${pids[@]}"; do kill -INT -- "-$p" 2>/dev/null || true; done
  for _ in $(seq 30); do
    alive=0
    for p in "${pids[@]}"; do kill -0 "$p" 2>/dev/null && alive=1; done
    [ "$alive" = 0 ] && return
    sleep 1
  done
  for p in "${pids[@]}"; do kill -KILL -- "-$p" 2>/dev/null || true; done
}
trap cleanup EXIT
setsid Xvfb "$DISPLAY" -screen 0 1400x900x24 -nolisten tcp > "$OUT/xvfb.log" 2>&1 &
pids+=($!)
sleep 2
echo "== replaying $BAG with rviz on $DISPLAY (rate $RATE, screenshot at $AT s of the run)"
setsid roslaunch -p "$PORT" "$ROOT/launch/replay.launch" bag:="$BAG" rate:="$RATE" rviz:=true \
  loop_closure:=true exit_at_end:=false start_delay:=8 \
  trajectory_path:="$OUT/trajectory.txt" map_path:="$OUT/map.bt" > "$OUT/replay.log" 2>&1 &
pids+=($!)

# Wait until the bag's clock is AT s past its start (the map has grown by then).
/usr/bin/python3 - "$BAG" "$AT" <<'EOF'
import sys, time
import rosbag, rospy
from rosgraph_msgs.msg import Clock
with rosbag.Bag(sys.argv[1]) as b:
    target = b.get_start_time() + float(sys.argv[2])
rospy.init_node("rviz_screenshot_wait", anonymous=True)
deadline = time.time() + 600
while time.time() < deadline:
    try:
        c = rospy.wait_for_message("/clock", Clock, timeout=5)
        if c.clock.to_sec() >= target:
            sys.exit(0)
    except rospy.ROSException:
        pass
sys.exit("the bag's clock never reached %.1f s" % target)
EOF
sleep 4  # rviz draws the last markers
xwd -root -display "$DISPLAY" -silent | convert xwd:- -colors 128 "png8:$PNG"
echo "rviz_screenshot.sh: $PNG ($(du -k "$PNG" | cut -f1) KB); logs in $OUT"
