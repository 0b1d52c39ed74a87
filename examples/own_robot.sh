#!/usr/bin/env bash
# Your robot in five commands, tried on dial_sim's robot profile (a JACO arm that publishes only
# jaco/joint_states, jaco/effort_command and jaco/skill_id; no markers, no sketch, pauses between
# episodes).  See examples/own_robot.py for the commands it runs (each one is printed as it runs):
#
#   1. record  bag_recorder (the three topics) while dial_sim --ros-args -p profile:=robot runs,
#              once for training episodes and once for held-out episodes (other seeds)
#   2. read    config/reader_dial_robot.yaml: observation = JointState position + velocity,
#              action = effort command, labels = skill ids, episodes split at the pauses
#   3. train   ompn_train --bags OUT/bags/train --config config/train_dial.yaml \
#                --set data.domain=null --set data.reader_spec=config/reader_dial_robot.yaml
#   4. segment ompn_segment --tune on the training bag (online detector settings for this model),
#              then ompn_segment --bag OUT/bags/heldout --checkpoint OUT/model/best \
#                --reader-config config/reader_dial_robot.yaml   (prints F1@1 and alignment)
#   5. live    ompn_node on jaco/joint_states: not wired yet (placeholder in own_robot.py)
#
# Usage: examples/own_robot.sh [--out DIR] [--episodes N] [--heldout M] [--iterations K] [--seed S]
# DDS stays on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) in ROS_DOMAIN_ID (1-100).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
python="${PYTHON:-$here/../.venv/bin/python}"
[ -x "$python" ] || python="python3"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$((RANDOM % 100 + 1))}"
exec "$python" "$here/own_robot.py" "$@"
