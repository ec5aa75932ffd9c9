#!/bin/sh
# Test double of `rosbag record` for rig_test_recorder_supervisor: takes the same options, writes
# its command line to $FAKE_ARGS, and behaves as $FAKE_MODE says:
#   record    opens <prefix>_<date>_0.bag.active, closes it to .bag on SIGINT (as rosbag does)
#   die       closes two bags, leaves the third open, prints rosbag's disk error, dies by SIGABRT
#   refuse    prints rosbag's open error and exits 1 without writing
[ -n "$FAKE_ARGS" ] && echo "$*" > "$FAKE_ARGS"
prefix=""
while [ $# -gt 0 ]; do
  [ "$1" = "-o" ] && prefix="$2"
  shift
done
stamp=2024-01-02-03-04-05
case "$FAKE_MODE" in
  record)
    bag="${prefix}_${stamp}_0.bag"
    echo header > "$bag.active"
    trap 'mv "$bag.active" "$bag"; exit 0' INT
    while :; do sleep 0.05; done
    ;;
  die)
    echo bag0 > "${prefix}_${stamp}_0.bag"
    echo bag1 > "${prefix}_${stamp}_1.bag"
    echo partial > "${prefix}_${stamp}_2.bag.active"
    printf '\033[31m[ERROR] [1700000000.000000]: Error writing to file: writing 8192 bytes, wrote 0 bytes\033[0m\n' >&2
    kill -ABRT $$
    ;;
  refuse)
    echo "[ERROR] [1700000000.000000]: Error writing: Error opening file: ${prefix}_${stamp}_0.bag.active" >&2
    exit 1
    ;;
esac
