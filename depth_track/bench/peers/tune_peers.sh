#!/usr/bin/env bash
# Parameter sweep of the peers on a run that is NOT one of the reported inputs: rendered rt2
# (ServoTrack, 95 mm/s with a +-10 deg yaw sine, chair room) with D435 noise (Kinect-class: 2-3 cm
# at 2-2.5 m), its first FRAMES frames. Prints ATE RMSE, median wall and CPU ms per frame for each
# setting; the most accurate (the faster one when within 10 %) is the default in peers.hpp.
#
#   depth_track/bench/peers/tune_peers.sh [OUTDIR] [open3d|ndt|gicp|all]   (FRAMES=60: 2 s of rt2)
#
# Normals are taken over twice the voxel size, as Open3D's tutorials do. The grid is small because
# every setting costs 1-8 s per frame on one core of this machine; 1 cm voxels (~4x the cost of
# 2 cm ones) were left out.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)"
BIN="${DT_PEERS:-$ROOT/devel/lib/depth_track/dt_peers}"
OUT="${1:-/tmp/dt_peers_tune}"
WHICH="${2:-all}"
FRAMES="${FRAMES:-60}"
RUN=(--render rt2 --noise d435 --frames "$FRAMES" --out-dir "$OUT")
mkdir -p "$OUT"
row() {  # method, then its options; prints the method's row of the dt_peers table
  local m="$1"; shift
  local line
  line=$(nice -n 10 "$BIN" "${RUN[@]}" --methods "$m" "$@" 2>/dev/null |
    awk -v m="$m" '$1 == m && $2 ~ /^[0-9]+$/')
  echo "$line" | awk -v m="$m" -v a="$*" \
    '{ printf "%-11s %-62s ate_m=%s med_ms=%s cpu_ms=%s flagged=%s\n", m, a, $3, $5, $8, $7 }'
}
want() { [ "$WHICH" = all ] || [ "$WHICH" = "$1" ]; }
if want open3d; then
  for vc in "0.02 0.05" "0.02 0.1" "0.02 0.2" "0.04 0.02" "0.04 0.05" "0.04 0.1"; do
    read -r v c <<<"$vc"
    r=$(awk -v v="$v" 'BEGIN { print 2 * v }')
    row open3d_p2l --o3d-voxel "$v" --o3d-normal-radius "$r" --o3d-max-corr "$c"
  done
fi
if want ndt; then
  # 2 cm input voxels (measured before: ATE 0.037 m at 0.1 m cells, 0.075 m at 0.2 m) cost ~8 s per
  # frame here; the sweep goes on with 5 cm ones.
  for vr in "0.05 0.1" "0.05 0.2" "0.05 0.3" "0.05 0.5" "0.08 0.2"; do
    read -r v res <<<"$vr"
    row pcl_ndt --ndt-voxel "$v" --ndt-resolution "$res"
  done
fi
if want gicp; then
  for vc in "0.02 0.05" "0.02 0.1" "0.04 0.03" "0.04 0.05" "0.04 0.1" "0.04 0.2" "0.06 0.05"; do
    read -r v c <<<"$vc"
    row pcl_gicp --gicp-voxel "$v" --gicp-max-corr "$c"
  done
fi
