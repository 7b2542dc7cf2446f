#!/usr/bin/env python3
"""Roundabout insertion judged on roundabouts never trained or tuned on (Python 3 stdlib only).

Training set (configs/insertion_rings_train.txt): montlake (bundled), tiny_roundabout, INTERACTION
FT and the even-numbered rings of the Andorra extract. Evaluation set
(configs/insertion_rings_eval.txt): Andorra's odd-numbered rings, Campo Grande, Krems and the
INTERACTION EP, SR, LN and OF maps. The world is the calibrated one (`calibration =` in the
recipe), at capacity-based traffic levels.

For each seed S: `agent train --maps configs/insertion_rings_train.txt --seed S` with the recipe (its
checkpoints chosen by validation episodes on the training rings only), then `agent eval --seed S`
on every evaluation ring beside the baselines (the same episodes for every policy). Finished
trainings and evaluations are reused.

    python3 scripts/unseen_roundabouts.py --recipe RECIPE.toml --work runs/unseen \
        [--seeds 0,1,2] [--episodes 50] [--traffic medium]

Prints and writes WORK/unseen.md and WORK/unseen.json: per policy, reaches and crashes over
the whole evaluation set (the agent: mean over seeds with their range and a t interval; a
baseline: pooled, Wilson interval), and the agent against each baseline paired episode by
episode, pooled over rings and seeds (exact McNemar on the discordant episodes).
"""
import argparse
import json
import math
import subprocess
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TRAIN_LIST = ROOT / "configs/insertion_rings_train.txt"
EVAL_LIST = ROOT / "configs/insertion_rings_eval.txt"


def read_list(path):
    """(path, ring or None) per line of a `--maps` list, paths from the list's folder."""
    out = []
    for line in path.read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            words = line.split()
            out.append(((path.parent / words[0]).resolve(), int(words[1]) if len(words) > 1 else None))
    return out


TRAIN = read_list(TRAIN_LIST)
EVAL = read_list(EVAL_LIST)
T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571}


def run(cmd, log):
    t0 = time.time()
    with open(log, "w") as f:
        f.write("$ " + " ".join(map(str, cmd)) + "\n")
        f.flush()
        rc = subprocess.run(list(map(str, cmd)), stdout=f, stderr=subprocess.STDOUT).returncode
    if rc != 0:
        raise SystemExit(f"failed ({rc}): see {log}")
    return time.time() - t0


def wilson(k, n):
    if n == 0:
        return (0.0, 1.0)
    z, p = 1.959964, k / n
    c = (p + z * z / (2 * n)) / (1 + z * z / n)
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (0.0 if k == 0 else c - h, 1.0 if k == n else c + h)


def mcnemar(b, c):
    n = b + c
    if n == 0:
        return 1.0
    k = min(b, c)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2 ** n
    return min(1.0, 2 * tail)


def name(path, ring):
    return path.name.split(".")[0] + ("" if ring is None else f"#{ring}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--pipeline", default=str(ROOT / "target/release/pipeline"))
    ap.add_argument("--recipe", required=True)
    ap.add_argument("--work", required=True, type=Path)
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--traffic", default="medium")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    args.work.mkdir(parents=True, exist_ok=True)
    listing = TRAIN_LIST

    per = {}  # (seed, eval name) -> eval.json
    for seed in seeds:
        agent = args.work / f"agent_{seed}"
        if not (agent / "task.json").exists():
            took = run([args.pipeline, "--rerun", "off", "--config", args.recipe, "--seed", seed,
                        "agent", "train", "--maps", listing, "--out", agent, "--traffic",
                        args.traffic, "--record-episodes", "0"], args.work / f"train_{seed}.log")
            print(f"seed {seed}: trained in {took / 60:.1f} min", flush=True)
        for path, ring in EVAL:
            out = args.work / f"eval_{seed}_{name(path, ring)}"
            if not (out / "eval.json").exists():
                cmd = [args.pipeline, "--rerun", "off", "--config", args.recipe, "--seed", seed,
                       "agent", "eval", "--agent", agent, "--map", path, "--episodes",
                       args.episodes, "--traffic", args.traffic, "--aggressiveness", "0.5",
                       "--record-episodes", "0", "--out", out]
                if ring is not None:
                    cmd += ["--roundabout", ring]
                run(cmd, args.work / f"eval_{seed}_{name(path, ring)}.log")
            per[(seed, name(path, ring))] = json.loads((out / "eval.json").read_text())

    # Pool: per policy, episodes reached / crashed over rings, per seed.
    stats = {}
    paired = {}
    for (seed, _), report in per.items():
        for cond in report["conditions"]:
            for p in cond["policies"]:
                s = stats.setdefault(p["policy"], {}).setdefault(seed, [0, 0, 0])
                n = p["episodes"]
                s[0] += round(p["reaches"] * n)
                s[1] += round(p["crashes"] * n)
                s[2] += n
            for t in cond.get("paired", []):
                q = paired.setdefault(t["baseline"], [0, 0, 0, 0])
                q[0] += t["reaches"]["only_first"]
                q[1] += t["reaches"]["only_second"]
                q[2] += t["crashes"]["only_first"]
                q[3] += t["crashes"]["only_second"]
    rows = []
    out = {"seeds": seeds, "episodes_per_ring": args.episodes, "traffic": args.traffic,
           "train": [name(p, r) for p, r in TRAIN], "eval": [name(p, r) for p, r in EVAL],
           "policies": {}, "paired": {}}
    for policy, by_seed in stats.items():
        rates = [v[0] / v[2] for v in by_seed.values()]
        crashes = [v[1] / v[2] for v in by_seed.values()]
        k = sum(v[0] for v in by_seed.values())
        c = sum(v[1] for v in by_seed.values())
        n = sum(v[2] for v in by_seed.values())
        entry = {"reaches": k / n, "crashes": c / n, "episodes": n,
                 "reaches_range": [min(rates), max(rates)],
                 "crashes_range": [min(crashes), max(crashes)]}
        if policy == "agent" and len(rates) > 1:
            m = sum(rates) / len(rates)
            sd = math.sqrt(sum((r - m) ** 2 for r in rates) / (len(rates) - 1))
            h = T975.get(len(rates) - 1, 1.96) * sd / math.sqrt(len(rates))
            entry["reaches_t95"] = [m - h, m + h]
        else:
            entry["reaches_ci95"] = wilson(k, n)
            entry["crashes_ci95"] = wilson(c, n)
        out["policies"][policy] = entry
    for baseline, q in paired.items():
        out["paired"][baseline] = {
            "reached_only_agent": q[0], "reached_only_baseline": q[1],
            "reaches_p": mcnemar(q[0], q[1]),
            "crashed_only_agent": q[2], "crashed_only_baseline": q[3],
            "crashes_p": mcnemar(q[2], q[3])}
    lines = [f"{len(EVAL)} evaluation rings, {args.episodes} episodes each per seed, seeds "
             f"{args.seeds}, traffic {args.traffic}, aggressiveness 0.5\n",
             "| policy | reached % (range) [95 %] | crashed % |", "| --- | --- | --- |"]
    for policy, e in out["policies"].items():
        ci = e.get("reaches_t95") or e["reaches_ci95"]
        lines.append(f"| {policy} | {100 * e['reaches']:.1f} ({100 * e['reaches_range'][0]:.1f}-"
                     f"{100 * e['reaches_range'][1]:.1f}) [{100 * ci[0]:.1f}, {100 * ci[1]:.1f}] | "
                     f"{100 * e['crashes']:.1f} |")
    lines += ["", "| agent against | reached: only agent / only baseline | p | crashed: only agent / "
              "only baseline | p |", "| --- | --- | --- | --- | --- |"]
    for b, q in out["paired"].items():
        lines.append(f"| {b} | {q['reached_only_agent']} / {q['reached_only_baseline']} | "
                     f"{q['reaches_p']:.2g} | {q['crashed_only_agent']} / "
                     f"{q['crashed_only_baseline']} | {q['crashes_p']:.2g} |")
    text = "\n".join(lines) + "\n"
    (args.work / "unseen.md").write_text(text)
    (args.work / "unseen.json").write_text(json.dumps(out, indent=1))
    print(text)


if __name__ == "__main__":
    main()
