#!/usr/bin/env bash
# The main job on a small default: list the suite, roll the scripted experts of a task out for both robots,
# and write what they did to a video and a rerun recording under outputs/.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"
task="${1:-door}"
mkdir -p outputs
mosaic-data tasks
mosaic-data experts --task "$task" --robot both --episodes 2 --video "outputs/${task}_experts.mp4"
mosaic-data experts --task "$task" --robot panda --episodes 1 --rerun "outputs/${task}_experts.rrd"
echo "done: outputs/${task}_experts.mp4 and outputs/${task}_experts.rrd (view with: .venv/bin/rerun outputs/${task}_experts.rrd)"
