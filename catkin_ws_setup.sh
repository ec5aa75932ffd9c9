#!/usr/bin/env bash
# Set up, build and (with --test) test the depth_track workspace on Debian 12.
#
#   ./catkin_ws_setup.sh            install missing Debian packages, build in Release
#   ./catkin_ws_setup.sh --test     ... then build and run every test (gtest + rostest) and end
#                                   with the line "N passed, N failed"; exit status 1 on any failure
#   ./catkin_ws_setup.sh --no-install   skip the package step (machine known to be set up)
#
# Idempotent: re-running only installs what is missing and rebuilds what changed.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
cd "$ROOT"

RUN_TESTS=0
INSTALL=1
JOBS="${JOBS:-2}"
for arg in "$@"; do
  case "$arg" in
    --test) RUN_TESTS=1 ;;
    --no-install) INSTALL=0 ;;
    -h|--help) sed -n '2,10p' "$0"; exit 0 ;;
    *) echo "catkin_ws_setup.sh: unknown option '$arg' (see --help)" >&2; exit 2 ;;
  esac
done

# ROS on Debian lives in /usr; a pyenv python3 first on PATH lacks the ROS Python modules.
export PATH="/usr/bin:/bin:/usr/sbin:/sbin:$PATH"

# ---- Debian packages -----------------------------------------------------------------------------
PACKAGES=(
  # toolchain and build
  build-essential cmake catkin python3-catkin-pkg python3-empy
  # ROS 1 from Debian
  ros-core-dev ros-base-dev ros-message-generation ros-message-runtime libroscpp-dev
  librosconsole-dev libnodeletlib-dev libnodelet-dev pluginlib-dev libtf2-dev libtf2-ros-dev
  libtf2-eigen-dev libtf2-geometry-msgs-dev libsensor-msgs-dev libstd-msgs-dev libstd-srvs-dev
  libgeometry-msgs-dev libnav-msgs-dev libvisualization-msgs-dev libimage-transport-dev
  image-transport-tools
  libpcl-conversions-dev libpcl-ros-dev librosbag-dev librostest-dev python3-rostest
  python3-rosbag python3-roslaunch python3-rosunit rosbash rviz
  # Python side of the graph's messages, so rostopic / rosmsg / rosservice can decode them
  python3-rostopic python3-rosnode python3-rosservice python3-rosmsg python3-genpy
  python3-std-msgs python3-std-srvs python3-sensor-msgs python3-geometry-msgs python3-nav-msgs
  python3-tf2-msgs python3-visualization-msgs python3-rosgraph-msgs python3-diagnostic-msgs
  # the graph's /diagnostics and runtime reconfiguration (C++ and the Python client)
  libdiagnostic-updater-dev libdynamic-reconfigure-config-init-mutex-dev python3-dynamic-reconfigure
  # core libraries
  libeigen3-dev libtbb-dev liboctomap-dev octomap-tools libpng-dev libnanoflann-dev
  libcli11-dev libyaml-cpp-dev
  # tests, benchmarks, fuzzing, serial ptys, evaluation
  libgtest-dev googletest libbenchmark-dev clang-14 libclang-rt-14-dev libfuzzer-14-dev socat
  python3-numpy python3-scipy python3-matplotlib
  # peer libraries of the side-by-side benchmark (depth_track/bench/peers; built when present)
  libopen3d-dev libpcl-dev
  # headless rviz screenshots (bags/rviz_screenshot.sh: virtual X server, screen grab, PNG)
  xvfb x11-apps imagemagick
  # the rig boards' firmware images (rig_drivers/scripts/build_firmware.sh) and the AVR emulator
  # their tests run them in (qemu-system-avr)
  gcc-avr avr-libc binutils-avr qemu-system-misc
)

if [ "$INSTALL" = 1 ]; then
  missing=()
  for p in "${PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if [ "${#missing[@]}" -gt 0 ]; then
    SUDO=""
    [ "$(id -u)" = 0 ] || SUDO="sudo"
    echo "== installing ${#missing[@]} Debian packages: ${missing[*]}"
    $SUDO apt-get update
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y --no-install-recommends "${missing[@]}"
  else
    echo "== all ${#PACKAGES[@]} Debian packages present"
  fi
fi

# ---- build ---------------------------------------------------------------------------------------
set +u
# shellcheck disable=SC1091
[ -f /opt/ros/noetic/setup.bash ] && source /opt/ros/noetic/setup.bash
set -u
CATKIN_ARGS=(-DCMAKE_BUILD_TYPE=Release -DPYTHON_EXECUTABLE=/usr/bin/python3 -DCATKIN_ENABLE_TESTING="$RUN_TESTS")

echo "== building (Release, $JOBS jobs)"
if ! catkin_make -C "$ROOT" "${CATKIN_ARGS[@]}" -j"$JOBS"; then
  echo "build failed" >&2
  [ "$RUN_TESTS" = 1 ] && echo "0 passed, 1 failed"
  exit 1
fi

if [ "$RUN_TESTS" = 0 ]; then
  echo "== built. Use:  source $ROOT/devel/setup.bash"
  exit 0
fi

# ---- tests ---------------------------------------------------------------------------------------
rm -rf "$ROOT/build/test_results" "$ROOT/build/ctest-exit-codes.xml"
echo "== building and running tests"
set +e
catkin_make -C "$ROOT" "${CATKIN_ARGS[@]}" -j"$JOBS" tests
build_rc=$?
if [ $build_rc -ne 0 ]; then
  echo "test build failed" >&2
  echo "0 passed, 1 failed"
  exit 1
fi
# Every declared test through ctest (catkin registers each gtest, rostest and the fuzz run there),
# one at a time: whole-run tests and rostests each take a core or two of their own. Unlike
# `catkin_make run_tests`, ctest keeps each command's exit status (build/ctest-exit-codes.xml), so
# the summary fails a binary that wrote passing results and then crashed. A test that hangs is
# stopped after DT_TEST_TIMEOUT_S (default 1800 s) and counts as failed.
# Tests that need the shared real data (TUM sequences, shared/tools) skip with the reason when
# it is missing; DT_REQUIRE_SHARED_DATA=1 (set by .ci/run) makes that a failure instead.
ctest --test-dir "$ROOT/build" --timeout "${DT_TEST_TIMEOUT_S:-1800}" --output-on-failure \
  --output-junit "$ROOT/build/ctest-exit-codes.xml"
set -e
/usr/bin/python3 "$ROOT/depth_track/scripts/test_summary.py" "$ROOT/build/test_results" \
  --source "$ROOT" --exit-codes "$ROOT/build/ctest-exit-codes.xml"
