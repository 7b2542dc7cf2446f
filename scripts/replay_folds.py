#!/usr/bin/env python3
"""Agreement of offline agents with drivers on recordings they were not trained on, every recording held out in turn.

For each of the ten FT recordings: `pipeline agent train --offline` on the nine others (the config given), then
`pipeline replay eval` of that agent on the held-out one. Prints each fold's agreement and the pooled one (the
frames the ten agents got right over all scored frames) and writes them as JSON. Folds run `--jobs` at a time,
each on one thread (RAYON_NUM_THREADS=1); the agents are deterministic, so the figures do not depend on that.

    python3 scripts/replay_folds.py --pipeline target/release/pipeline --logs runs/ft \\
        --config configs/offline_ft_motion.toml --algorithm bc --work runs/ft/folds_bc --out FOLDS.json

--logs holds ft_000.mcap ... ft_009.mcap (`pipeline logs convert`, docs/logs.md). A fold whose agent and replay
are already in --work is not run again.
"""

import argparse
import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

SHARED = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data")
MAP = os.path.join(SHARED, "trajectories", "interaction", "maps", "DR_USA_Roundabout_FT.osm")
NAMES = [f"ft_{i:03d}" for i in range(10)]


def run(cmd, log):
    with open(log, "w") as f:
        done = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT,
                              env={**os.environ, "RAYON_NUM_THREADS": "1"})
    if done.returncode != 0:
        sys.exit(f"error: {' '.join(cmd)} failed (exit {done.returncode}); see {log}")


def fold(args, held):
    agent = os.path.join(args.work, f"{held}_agent")
    replay = os.path.join(args.work, f"{held}_replay")
    if not os.path.isfile(os.path.join(agent, "offline.json")):
        train = [n for n in NAMES if n != held]
        cmd = [args.pipeline, "--rerun", "off", "--seed", str(args.seed), "--config", args.config,
               "agent", "train", "--offline", "--algorithm", args.algorithm, "--map", MAP, "--out", agent]
        for n in train:
            cmd += ["--log", os.path.join(args.logs, n + ".mcap")]
        run(cmd, agent + ".log")
    if not os.path.isfile(os.path.join(replay, "replay.json")):
        cmd = [args.pipeline, "--rerun", "off", "replay", "eval", "--log", os.path.join(args.logs, held + ".mcap"),
               "--map", MAP, "--agent", agent, "--aggressiveness", args.aggressiveness, "--out", replay]
        run(cmd, replay + ".log")
    with open(os.path.join(replay, "replay.json")) as f:
        report = json.load(f)
    levels = {}
    for policy in report["policies"]:
        if policy["policy"].startswith("agent"):
            c = policy["confusion"]
            levels[policy["policy"]] = {"right": c["go"]["go"] + c["wait"]["wait"],
                                        "frames": sum(c[h][a] for h in c for a in c[h])}
    return held, levels


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pipeline", default="target/release/pipeline")
    ap.add_argument("--logs", required=True, help="folder with ft_000.mcap ... ft_009.mcap")
    ap.add_argument("--config", required=True, help="the offline agent's config (configs/offline_ft_motion.toml)")
    ap.add_argument("--algorithm", default="cql", choices=["cql", "bc"])
    ap.add_argument("--aggressiveness", default="0,0.5,1")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", required=True, help="folder for the ten agents and replays")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", help="write the figures as JSON here")
    args = ap.parse_args()
    os.makedirs(args.work, exist_ok=True)
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        folds = dict(pool.map(lambda held: fold(args, held), NAMES))
    result = {"config": args.config, "algorithm": args.algorithm, "seed": args.seed, "folds": folds, "pooled": {}}
    for level in next(iter(folds.values())):
        right = sum(f[level]["right"] for f in folds.values())
        frames = sum(f[level]["frames"] for f in folds.values())
        result["pooled"][level] = right / frames
        per = ", ".join(f"{h} {100 * f[level]['right'] / f[level]['frames']:.1f}" for h, f in folds.items())
        print(f"{level}: pooled {100 * right / frames:.2f} % of {frames} frames ({per})")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=2)
            f.write("\n")


if __name__ == "__main__":
    main()
