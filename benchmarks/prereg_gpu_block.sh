#!/bin/bash
# Advance a pre-registered design's gpu-scale runs by one block on a lent GPU, trained by the code of the
# design's commit (the design's file's last commit), whatever main has moved to. Every condition of the
# design runs side by side on the one GPU, each a vmapped program of the design's seeds, resumed from the
# last block's state; a block ends after STOP seconds by killing the runs (each keeps its latest checkpoint:
# --checkpoint-every 10 loses at most one 10-iteration chunk). Three steps:
#
#   here:    bash benchmarks/prereg_gpu_block.sh prepare h1_prereg
#            (.prereg/: the design commit's code, its commands, the state so far; .whl/: tyro's wheels; and
#            the records and the committed state (copied into .prereg/state) left out of git's index, so the
#            tree that travels stays under the device's 64 MiB)
#   device:  run(command="bash .prereg/block.sh device 450", carry=[".prereg", ".whl"], timeout_s=560)
#   here:    bash benchmarks/prereg_gpu_block.sh collect DIR     (DIR: the files_at of that call)
#            (the state and commands log back into .prereg/, the records back into the index, and the
#            block's progress and slimmed resume state into benchmarks/results/inflight/<design>-gpu/ to
#            commit: state/<run>.tgz, the latest checkpoint every seed has, one copy, replaced each block;
#            prepare copies it into an empty .prereg/state, so another workspace resumes from git)
#
# .prereg/state/<condition>.tgz holds each run directory with only its latest checkpoint (and policy);
# BLOCK_EXTRA="FLAGS" appends flags to every run (a smoke test off the GPU, e.g. --num-envs 4).
# .prereg/commands.log is the commands log `experiments record --commands-log` reads once the runs end.
set -euo pipefail

blind() {  # progress lines with iterations and speed only: a design's returns stay unread until it is complete
  sed -E 's/ return\[[^]]*\]=[^ ]*//g' | { grep -viE 'return|learned|plateau|score' || true; }
}

prepare() {
  local design=$1
  local commit
  commit=$(git log -1 --format=%H -- "jaxsocial/experiments/designs/$design.json")
  [ -n "$commit" ] || { echo "error: design $design is not committed" >&2; exit 1; }
  mkdir -p .prereg/state .whl
  local committed=benchmarks/results/inflight/$design-gpu/state
  if [ -z "$(ls .prereg/state)" ] && [ -d "$committed" ]; then  # a workspace without the state: git's
    for t in "$committed"/*.tgz; do  # (<run>/...) under the device's tree (runs/experiments/gpu/<run>/...)
      local tmp
      tmp=$(mktemp -d) && mkdir -p "$tmp/runs/experiments/gpu"
      tar xzf "$t" -C "$tmp/runs/experiments/gpu" && tar czf ".prereg/state/$(basename "$t")" -C "$tmp" runs
      rm -rf "$tmp"
    done
  fi
  rm -rf .prereg/code && mkdir .prereg/code && git archive "$commit" | tar -x -C .prereg/code
  (cd .prereg/code && PYTHONPATH=$PWD python -m jaxsocial.experiments run "$design" --scale gpu --dry-run) |
    grep "python -m jaxsocial.train" | sed 's/^ *python -m jaxsocial.train //' >.prereg/commands.txt
  printf '%s\n%s\n' "$commit" "$design" >.prereg/design.txt
  python -c "from jaxsocial.experiments.plan import designs; print(designs.load('$design').xla_flags or '')" \
    >.prereg/xla_flags.txt  # the design's own (designs since 2026-11-28), set on the device for every run
  cp "$0" .prereg/block.sh
  python -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux2014_x86_64 -d .whl tyro==1.0.17 docstring-parser==0.18.0 typeguard==4.6.1
  for path in /.prereg/ /.whl/ /benchmarks/results/records/ "/$committed/"; do
    grep -qxF "$path" .git/info/exclude || echo "$path" >>.git/info/exclude
  done
  git rm -r -q --cached --ignore-unmatch benchmarks/results/records "$committed"  # .prereg/state has it
  echo "prepared $design at $commit: $(wc -l <.prereg/commands.txt) runs; state: $(ls .prereg/state)"
  echo "the records are out of the index until 'collect' (do not commit before it)"
}

device() {
  set +e  # a block always ends by packing what its runs reached
  local stop=$1 commit root=$PWD
  commit=$(head -1 .prereg/design.txt)
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
  export PYTHONPATH=$root/.prereg/code:/tmp/site PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
  cd .prereg/code
  for t in ../state/*.tgz; do
    if [ -f "$t" ]; then tar xzf "$t"; fi
  done
  cp ../commands.log "$OUT/commands.log" 2>/dev/null || : >"$OUT/commands.log"
  export XLA_FLAGS
  XLA_FLAGS=$(cat ../xla_flags.txt 2>/dev/null)
  local machine  # where this block's runs train, $XLA_FLAGS included, for the records' provenance
  machine=$(PYTHONPATH=$root:/tmp/site python3 -c 'import json, os
from jaxsocial.run import provenance
print(json.dumps(provenance.machine(os.environ.get("XLA_FLAGS", ""))))') &&
    echo "$(date -u +%Y-%m-%dT%H:%M:%SZ) machine $machine" >>"$OUT/commands.log"
  nvidia-smi -L
  python3 -c 'import jax, flax, tyro; print("jax", jax.__version__, "flax", flax.__version__, jax.devices())'
  while read -r args; do
    local run=${args##*--run-name } resume=""
    run=${run%% *}
    [ -f "runs/experiments/$run/config.json" ] && resume="--resume "
    local condition=${run##*/}
    condition=${condition%-s*}
    echo "$(date -u +%Y-%m-%dT%H:%M:%SZ) $commit python -m jaxsocial.train $resume$args --checkpoint-every 10" \
      >>"$OUT/commands.log"
    (
      t0=$SECONDS
      python3 -m jaxsocial.train $resume$args --checkpoint-every 10 ${BLOCK_EXTRA:-} >"$OUT/$condition.log" 2>&1
      rc=$?
      echo "$(date -u +%Y-%m-%dT%H:%M:%SZ) done $condition rc=$rc $((SECONDS - t0))s" >>"$OUT/commands.log"
    ) &
  done <../commands.txt
  local end=$((SECONDS + stop))
  while [ $SECONDS -lt $end ] && [ -n "$(jobs -rp)" ]; do sleep 2; done
  pkill -KILL -f jaxsocial.train && echo "stopped the runs after ${stop}s"
  wait
  python3 - <<'PRUNE'
import pathlib, shutil
for run in sorted(p for p in pathlib.Path("runs/experiments/gpu").iterdir() if p.is_dir()):
    seeds = sorted(d for d in run.iterdir() if d.is_dir() and d.name[1:].isdigit())
    steps = [{int(p.name) for p in (d / "checkpoints").glob("*") if p.name.isdigit()} for d in seeds]
    common = set.intersection(*steps) if steps else set()
    keep = str(max(common)) if common else None
    for d in seeds:
        for sub in ("checkpoints", "policy"):
            for p in (d / sub).glob("*"):
                if p.name != keep:
                    shutil.rmtree(p) if p.is_dir() else p.unlink()
    print(f"{run.name}: latest checkpoint every seed has: {keep}")
PRUNE
  for run in runs/experiments/gpu/*/; do
    local condition
    condition=$(basename "$run")
    condition=${condition%-s*}
    tr '\r' '\n' <"$OUT/$condition.log" | grep -v '^\s*$' | blind | tail -1
    mv "$OUT/$condition.log" "$run/device-$(date -u +%Y%m%dT%H%M%S).log"
    tar czf "$OUT/$condition.tgz" "$run"
  done
  cat "$OUT/commands.log"
}

collect() {
  local from=$1 design
  design=$(sed -n 2p .prereg/design.txt)
  local committed=benchmarks/results/inflight/$design-gpu/state
  git reset -q -- benchmarks/results/records "$committed"
  sed -i -e '\|^/benchmarks/results/records/$|d' -e "\\|^/$committed/\$|d" .git/info/exclude
  cp "$from"/*.tgz .prereg/state/ && chmod u+w .prereg/state/*.tgz
  cp "$from/commands.log" .prereg/commands.log && chmod u+w .prereg/commands.log
  local out=benchmarks/results/inflight/$design-gpu tmp
  tmp=$(mktemp -d)
  for t in .prereg/state/*.tgz; do tar xzf "$t" -C "$tmp"; done
  # Earlier blocks' blinded logs stay (device-<UTC time>.log, one a block): the committed state no longer
  # carries the raw logs, so a block resumed from git brings back only its own.
  rm -rf "$out/state" && mkdir -p "$out"
  cp .prereg/commands.log "$out/commands.log"
  python -m jaxsocial.experiments inflight .prereg/state/*.tgz --out "$out/state"  # the resume state, in git
  for run in "$tmp"/runs/experiments/gpu/*/; do
    local name
    name=$(basename "$run")
    mkdir -p "$out/$name"
    for log in "$run"device-*.log; do  # progress lines end in carriage returns: one line each
      if [ -f "$log" ]; then tr '\r' '\n' <"$log" | grep -v '^\s*$' | blind >"$out/$name/$(basename "$log")"; fi
    done
    for seed in "$run"s*/; do
      mkdir -p "$out/$name/$(basename "$seed")"
      cp "$seed/config.json" "$out/$name/$(basename "$seed")/"
      gzip -n -c "$seed/metrics.jsonl" >"$out/$name/$(basename "$seed")/metrics.jsonl.gz"
    done
  done
  rm -rf "$tmp"
  python - "$out" <<'PROGRESS'
import gzip, json, pathlib, statistics, sys
out = pathlib.Path(sys.argv[1])
progress = {}
for run in sorted(p for p in out.iterdir() if any(p.glob("s*/config.json"))):  # not state/
    seeds = sorted(p.parent for p in run.glob("s*/config.json"))
    config = json.loads((seeds[0] / "config.json").read_text())
    rows = [json.loads(line) for line in gzip.open(seeds[0] / "metrics.jsonl.gz", "rt")]
    progress[run.name] = {
        "iterations_done": len(rows),
        "iterations": config["iterations"],
        "env_steps_per_seed": len(rows) * config["num_envs"] * config["rollout_steps"],
        "seeds": len(seeds),
        "median_program_env_steps_per_s": statistics.median(r["env_steps_per_s"] for r in rows) * len(seeds),
    }
(out / "progress.json").write_text(json.dumps(progress, indent=1) + "\n")
print(json.dumps(progress, indent=1))
PROGRESS
  echo "collected into .prereg/ and $out (commit it now: its state/ resumes the runs from any workspace)"
}

"$@"
