#!/usr/bin/env bash
# The exploratory pilots of the transfer8 design (jaxsocial/experiments/designs/transfer8.json),
# played before it was committed, into benchmarks/results/science/transfer8-evidence/:
#   sizes: the 8x8 screen's PPO + pred seeds (sweep settings mb8k8_pred_8x8 and mb8k8_solo_pred_8x8, seeds
#          0-6, other records than pred8's) and a random walker in the learner's slot, beside each
#          environment's navigator experts, at the smallest Four Rooms and Maze sizes and the next ones;
#   power: the experts design's 80 PPO + rec records (other records than pred8's) in each primary
#          environment the sizes pilot chose: 8x8 4-goal Goal Cycle, 9x9 Four Rooms and 7x7 Maze, beside
#          each environment's experts.
# 128 episodes a policy, evaluation seed 0, as the designs play. Usage: bash benchmarks/transfer8_pilot.sh
set -euo pipefail
out=benchmarks/results/science/transfer8-evidence
mkdir -p "$out"
sweep=benchmarks/results/records/sweep
experts=benchmarks/results/records/laptop/prereg-experts
play() {  # play FILE ENV [evaluate flags...]: one evaluation, skipped where its file exists
  local file="$out/$1" env="$2"; shift 2
  [[ -e "$file" ]] || python -m jaxsocial.evaluate --env "$env" --episodes 128 --seed 0 --out "$file" "$@"
}
for env in maze:width=7,height=7 fourrooms:width=9,height=9 maze:width=9,height=9 fourrooms:width=11,height=11; do
  tag=$(echo "$env" | tr ':,' '__')
  play "$tag-social_pred.json" "$env" --ckpt $(printf "$sweep/mb8k8_pred_8x8/s%d " 0 1 2 3 4 5 6)
  play "$tag-solo_pred.json" "$env" --ckpt $(printf "$sweep/mb8k8_solo_pred_8x8/s%d " 0 1 2 3 4 5 6)
  play "$tag-random.json" "$env" --slots random,expert:navigator,expert:navigator
done
for env in goalcycle4:width=8,height=8 fourrooms:width=9,height=9 maze:width=7,height=7; do
  tag=$(echo "$env" | tr ':,' '__')
  for arm in social_rec solo_rec; do
    play "$tag-$arm.json" "$env" --ckpt $(for s in $(seq 300 339); do printf "$experts/$arm-s$s-$s "; done)
  done
done
