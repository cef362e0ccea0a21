#!/usr/bin/env bash
# The main job on a bundled real pair: set up, start the installed register_node, publish the
# pair to it (source turned by a random rotation about its sensor), print the pose and its error.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/environment.sh
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-77}"
lib=install/regor_ros/lib/regor_ros
share=install/regor_ros/share/regor_ros

echo "== starting register_node (indoor preset)"
"$lib/register_node" --ros-args --params-file "$share/config/indoor.yaml" &
node=$!
trap 'kill -INT $node 2>/dev/null; wait $node 2>/dev/null || true' EXIT
echo "== publishing the bundled 3DMatch pair (redkitchen 5/6)"
"$lib/regor-pair-client" "$share/demo/src.npy" "$share/demo/tgt.npy" \
  --ground-truth "$share/demo/gt.txt" --rotate "${SEED:-7}"
