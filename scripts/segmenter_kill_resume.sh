#!/bin/bash
# `kill -9` during `pipeline segmenter train`, then `--resume`; compares the
# resumed run with an uninterrupted one (checkpoint bytes and curve points).
# Usage: scripts/segmenter_kill_resume.sh PIPELINE_BINARY DATASET_DIR WORK_DIR
set -euo pipefail
P=$1 DATA=$2 WORK=$3
mkdir -p "$WORK" && cd "$WORK" && rm -rf run run.* straight
ARGS=(segmenter train --data "$DATA" --epochs 5 --size 128 --crop 128 --samples-per-epoch 48
      --val-limit 16 --batch-size 8 --threads 2)
"$P" --rerun save "${ARGS[@]}" --out run > first.log 2>&1 &
PID=$!
# Wait until epoch 2 is checkpointed, then kill -9 a few seconds into what follows.
until grep -qs '"kind":"epoch","epoch":2' run*/curves.jsonl; do sleep 1; done
sleep 4
echo "killed after $(grep -c '"kind":"epoch"' run*/curves.jsonl) epochs and $(grep -c '"kind":"step"' run*/curves.jsonl) steps"
kill -9 "$PID"; wait "$PID" 2>/dev/null || true
"$P" --rerun save "${ARGS[@]}" --out run --resume > resume.log 2>&1
head -1 resume.log
"$P" --rerun off "${ARGS[@]}" --out straight > straight.log 2>&1
for f in checkpoint/model.bpk checkpoint/optimizer.bpk best/model.bpk; do
    cmp -s "run/$f" "straight/$f" && echo "$f: identical to the uninterrupted run" || echo "$f: DIFFERS"
done
python3 - <<'PY'
import json
strip = lambda p: [{k: v for k, v in json.loads(l).items() if k != "seconds"} for l in open(p)]
a, b = strip("run/curves.jsonl"), strip("straight/curves.jsonl")
print(f"curve points: resumed {len(a)}, uninterrupted {len(b)}, equal apart from wall time: {a == b}")
PY
