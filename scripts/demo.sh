#!/usr/bin/env bash
# The main job on a small default (task `door`, or the first argument):
#   1. the task table and the scripted experts of both robots -> outputs/<task>_experts.mp4
#   2. a small cross-embodiment LeRobot dataset pair (2 episodes per variation per robot) -> outputs/datasets/mosaic/<task>_{panda,sawyer}
#   3. validation of both datasets, and a rerun recording of an agent episode beside a demonstrator episode
#   4. a few training steps of MOSAIC with lerobot-train on that pair -> outputs/train/<task>_mosaic
#   5. one-shot evaluation of that checkpoint beside the expert row (1 episode per variation), with a rerun
#      recording of the demonstrations, the policy's attention and its actions -> outputs/eval/<task>
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."  # paths below are relative to the repository root
source scripts/setup.sh
task="${1:-door}"
datasets="outputs/datasets"
mkdir -p outputs

mosaic-data tasks --task "$task"
mosaic-data experts --task "$task" --robot both --episodes 2 --video "outputs/${task}_experts.mp4"

mosaic-data collect --task "$task" --robot both --episodes 2 --output-dir "$datasets"
mosaic-data validate "mosaic/${task}_panda" --output-dir "$datasets"
mosaic-data validate "mosaic/${task}_sawyer" --output-dir "$datasets"
mosaic-data view "mosaic/${task}_panda" --episode 0 --pair --output-dir "$datasets" --save "outputs/${task}_pair.rrd"

rm -rf "outputs/train/${task}_mosaic"
lerobot-train --policy.type=mosaic \
    --dataset.repo_id="mosaic/${task}_panda" --dataset.root="$datasets/mosaic/${task}_panda" \
    --policy.demo_repo_id="mosaic/${task}_sawyer" --policy.demo_root="$datasets/mosaic/${task}_sawyer" \
    --policy.push_to_hub=false --policy.device=cpu \
    --steps=4 --batch_size=2 --num_workers=0 --save_freq=4 --log_freq=1 \
    --output_dir="outputs/train/${task}_mosaic"

mosaic-eval --policy.path="outputs/train/${task}_mosaic/checkpoints/last/pretrained_model" --baseline expert \
    --task "$task" --episodes-per-variation 1 --rerun "outputs/eval/${task}/eval.rrd" --output "outputs/eval/${task}/results.json"
echo "done: outputs/${task}_experts.mp4, datasets under $datasets, outputs/${task}_pair.rrd" \
     "(view with: .venv/bin/rerun outputs/${task}_pair.rrd), checkpoint outputs/train/${task}_mosaic/checkpoints/last," \
     "evaluation outputs/eval/${task}/results.md and eval.rrd"
