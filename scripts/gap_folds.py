#!/usr/bin/env python3
"""Gap acceptance, leave one recording out over INTERACTION's FT recordings, and EP scored
with policies fitted on every FT recording: `pipeline replay gaps` per fold, then the
held-out folds pooled (accuracy, balanced accuracy, 95 % bootstrap intervals over
approaches, the paired bootstrap against the fitted critical-gap rule).

    python3 scripts/gap_folds.py [--pipeline target/release/pipeline] [--work /tmp/gap_folds]

Converts the recordings it needs from ../shared/data (`logs convert`) into --work first.
Prints the pooled tables (markdown) and writes folds.json into --work.
"""

import argparse
import csv
import json
import random
import subprocess
from collections import defaultdict
from pathlib import Path

DATA = Path(__file__).resolve().parent.parent.parent / "shared/data/trajectories/interaction"
FT = [f"{i:03d}" for i in range(10)]
EP = ["000", "001"]
REFERENCE = "critical gap (maximum likelihood)"


def run(cmd):
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def convert(pipeline, work, place, k):
    out = work / f"{place.lower()}_{k}.mcap"
    if not out.exists():
        run([pipeline, "--rerun", "off", "logs", "convert",
             str(DATA / f"recorded_trackfiles/DR_USA_Roundabout_{place}/vehicle_tracks_{k}.csv.gz"),
             "--map", str(DATA / f"maps/DR_USA_Roundabout_{place}.osm"), "--out", str(out)])
    return out


def gaps(pipeline, out, logs, train, place, train_map=None):
    if not (out / "gaps.csv").exists():
        cmd = [pipeline, "--rerun", "off", "replay", "gaps", "--map",
               str(DATA / f"maps/DR_USA_Roundabout_{place}.osm"), "--out", str(out)]
        for log in logs:
            cmd += ["--log", str(log)]
        for log in train:
            cmd += ["--train-log", str(log)]
        if train_map:
            cmd += ["--train-map", str(train_map)]
        run(cmd)
    with open(out / "gaps.csv") as f:
        return list(csv.DictReader(f))


def pooled(rows, seed=0, replicates=2000):
    """Per policy: accuracy, balanced accuracy, their intervals, paired difference to the
    reference, over approaches (recording, track) resampled together."""
    columns = list(rows[0])
    policies = columns[columns.index("rejected_before") + 1:]  # after the last feature
    clusters = defaultdict(list)
    for r in rows:
        clusters[(r["recording"], r["track"])].append(r)
    keys = sorted(clusters)
    rng = random.Random(seed)
    picks = [[rng.randrange(len(keys)) for _ in keys] for _ in range(replicates)]

    def figures(sample, policy):
        c = defaultdict(int)
        for r in sample:
            c[(r["accepted"] == "1", r[policy] == "1")] += 1
        n = sum(c.values())
        acc = (c[(True, True)] + c[(False, False)]) / max(n, 1)
        parts = []
        for truth in (True, False):
            m = c[(truth, True)] + c[(truth, False)]
            if m:
                parts.append(c[(truth, truth)] / m)
        return acc, sum(parts) / max(len(parts), 1)

    def interval(xs):
        xs = sorted(xs)
        return xs[int(0.025 * (len(xs) - 1))], xs[int(0.975 * (len(xs) - 1))]

    samples = [[r for i in p for r in clusters[keys[i]]] for p in picks]
    out = {}
    for policy in policies:
        acc, bal = figures(rows, policy)
        reps = [figures(s, policy) for s in samples]
        entry = {"accuracy": acc, "balanced_accuracy": bal,
                 "ci95": interval([a for a, _ in reps]),
                 "balanced_ci95": interval([b for _, b in reps])}
        if policy != REFERENCE and REFERENCE in policies:
            ref = [figures(s, REFERENCE)[0] for s in samples]
            diffs = [a - r for (a, _), r in zip(reps, ref)]
            below = sum(d <= 0 for d in diffs)
            above = sum(d >= 0 for d in diffs)
            entry["vs_reference"] = acc - figures(rows, REFERENCE)[0]
            entry["vs_reference_ci95"] = interval(diffs)
            entry["p_value"] = min(1.0, 2 * max(min(below, above), 1) / len(diffs))
        out[policy] = entry
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--pipeline", default="target/release/pipeline")
    ap.add_argument("--work", default="/tmp/gap_folds", type=Path)
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    ft = [convert(args.pipeline, args.work, "FT", k) for k in FT]
    ep = [convert(args.pipeline, args.work, "EP", k) for k in EP]
    folds = []
    for i, log in enumerate(ft):
        rows = gaps(args.pipeline, args.work / f"fold_ft_{FT[i]}", [log],
                    [t for j, t in enumerate(ft) if j != i], "FT")
        folds.append(rows)
    ep_rows = gaps(args.pipeline, args.work / "ep_from_ft", ep, ft, "EP",
                   DATA / "maps/DR_USA_Roundabout_FT.osm")
    ft_rows = [r for rows in folds for r in rows]
    result = {"ft_leave_one_out": pooled(ft_rows), "ep_from_ft": pooled(ep_rows),
              "offered": {"ft": len(ft_rows), "ep": len(ep_rows)},
              "accepted": {"ft": sum(r["accepted"] == "1" for r in ft_rows),
                           "ep": sum(r["accepted"] == "1" for r in ep_rows)},
              "per_fold": {FT[i]: pooled(rows, replicates=200) for i, rows in enumerate(folds)}}
    (args.work / "folds.json").write_text(json.dumps(result, indent=1))
    for name in ("ft_leave_one_out", "ep_from_ft"):
        print(f"\n## {name}: {result['offered'][name.split('_')[0]]} gaps\n")
        print("| policy | accuracy % [95 %] | balanced % [95 %] | vs ML rule, points [95 %] | p |")
        print("| --- | --- | --- | --- | --- |")
        for policy, e in result[name].items():
            vs = (f"{100 * e['vs_reference']:+.1f} [{100 * e['vs_reference_ci95'][0]:+.1f}, "
                  f"{100 * e['vs_reference_ci95'][1]:+.1f}] | {e['p_value']:.3f}"
                  if "vs_reference" in e else "reference | -")
            print(f"| {policy} | {100 * e['accuracy']:.1f} [{100 * e['ci95'][0]:.1f}, "
                  f"{100 * e['ci95'][1]:.1f}] | {100 * e['balanced_accuracy']:.1f} "
                  f"[{100 * e['balanced_ci95'][0]:.1f}, {100 * e['balanced_ci95'][1]:.1f}] | {vs} |")
    print("\nper fold, accuracy %:")
    for k, e in result["per_fold"].items():
        print(k, {p: round(100 * v["accuracy"], 1) for p, v in e.items()})


if __name__ == "__main__":
    main()
