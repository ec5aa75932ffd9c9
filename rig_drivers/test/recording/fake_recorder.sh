#!/bin/sh
# Test double of `rosbag record` for rig_test_recorder_supervisor: takes the same options, writes
# its command line to $FAKE_ARGS, and behaves as $FAKE_MODE says:
#   record    opens <prefix>_<date>_0.bag.active, closes it to .bag on SIGINT (as rosbag does)
#   die       closes two bags, leaves the third open with data in it, prints rosbag's disk
#             errors, dies by SIGABRT
#   refuse    creates its first bag, prints rosbag's write error and exits 1 with the bag empty
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
    head -c 6000 /dev/zero > "${prefix}_${stamp}_2.bag.active"
    printf '\033[31m[ERROR] [1700000000.000000]: Problem writing data to disk\033[0m\n' >&2
    printf '\033[31m[ERROR] [1700000000.000000]: ROSLZ4_ERROR: compression error\033[0m\n' >&2
    kill -ABRT $$
    ;;
  refuse)
    : > "${prefix}_${stamp}_0.bag.active"
    echo "[ERROR] [1700000000.000000]: Error writing: Error writing to file: writing 4027 bytes, wrote 0 bytes" >&2
    exit 1
    ;;
esac
