#!/bin/bash
# Trains and evaluates one agent per seed with the same config, and prints each seed's
# per-condition reach rate: how much a result depends on the training seed.
# Usage: scripts/agent_seeds.sh PIPELINE CONFIG TASK OUT_DIR EPISODES SEED... [-- extra train args]
set -euo pipefail
P=$1 CONFIG=$2 TASK=$3 OUT=$4 EPISODES=$5
shift 5
SEEDS=()
while [ $# -gt 0 ] && [ "$1" != "--" ]; do SEEDS+=("$1"); shift; done
[ $# -gt 0 ] && shift
mkdir -p "$OUT"
for seed in "${SEEDS[@]}"; do
    agent="$OUT/seed_$seed"
    rm -rf "$agent" "$agent.partial"
    start=$(date +%s.%N)
    "$P" --config "$CONFIG" --seed "$seed" --rerun off agent train --task "$TASK" --out "$agent" \
        --record-episodes 0 "$@" > "$OUT/train_$seed.log" 2>&1
    end=$(date +%s.%N)
    "$P" --rerun off agent eval --agent "$agent" --episodes "$EPISODES" --out "$agent/eval" \
        > "$OUT/eval_$seed.log" 2>&1
    python3 - "$agent/eval/eval.json" "$seed" "$(echo "$end - $start" | bc)" <<'PY'
import json, sys
report = json.load(open(sys.argv[1]))
cells = []
for c in report["conditions"]:
    agent = next(p for p in c["policies"] if p["policy"] == "agent")
    cells.append(f'{c["condition"]}: reached {100 * agent["reaches"]:.1f} %, crashed {100 * agent["crashes"]:.1f} %')
print(f"seed {sys.argv[2]} (trained in {float(sys.argv[3]):.0f} s): " + "; ".join(cells))
PY
done
