#!/usr/bin/env python3
"""An insertion agent trained on a single-lane ring (montlake), evaluated on every two-lane ring
of the Andorra extract beside the baselines, over several training seeds (Python 3 stdlib only).

For each seed S: `agent train` on montlake with the recipe (`--seed S`), then `agent eval` with
`--seed S` on each two-lane ring (`--roundabout ID`) and on montlake (the seen ring).
Agent and baselines run the same episodes of one evaluation; episode k of seed S is the same
traffic for every policy, so the comparison with the best baseline is paired episode by episode.

Usage (from the repository root; finished trainings and evaluations are reused):
    python3 scripts/eval_unseen_rings.py [--pipeline target/release/pipeline] --work runs/unseen_rings \
        --seeds 0,2,3 --episodes 100 --montlake-episodes 300 \
        [--steps 60000 --checkpoint-every 15000 --validation-episodes 50]
(the last three: a longer run whose checkpoint validation on the training map chooses; not used so far).
A table of only the episodes where the ego starts before its yield line is added: on some entries of
some rings it starts at or past the line and no policy has a decision to make.
Writes WORK/unseen_rings.md (the tables) and WORK/unseen_rings.json, and prints the tables.

Intervals (95 %): a trained agent's rate is the mean over seeds, its range, and a t interval over
the seed means (seed-to-seed variation; n - 1 degrees of freedom). A baseline's rate pools the
episodes of every seed, with a Wilson interval. The paired difference with the best baseline (the
highest reach rate on the same rings) is given per seed, as a t interval over seeds, and pooled
over episodes (episodes as units, mean +- 1.96 sd / sqrt(n)), with an exact sign test on the
episodes where exactly one of the two reached.
"""
import argparse
import csv
import json
import math
import os
import re
import statistics
import subprocess
import sys
import time

AGENT = "agent"
NOT_PERMITTED = "always not permitted"
OUTCOMES = ("reached", "crashed", "time_over", "off_road")
T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262}


def run(cmd, log):
    t0 = time.time()
    with open(log, "w") as f:
        f.write("$ " + " ".join(cmd) + "\n")
        f.flush()
        rc = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT).returncode
    return rc, time.time() - t0


def tail(path, n=3):
    with open(path) as f:
        lines = [l.strip() for l in f if l.strip()]
    return " | ".join(lines[-n:])


def wilson(k, n):
    if n == 0:
        return (float("nan"),) * 2
    z = 1.96
    p = k / n
    c = (p + z * z / (2 * n)) / (1 + z * z / n)
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, c - h), min(1.0, c + h)


def t_interval(xs):
    m = statistics.fmean(xs)
    if len(xs) < 2:
        return m, float("nan"), float("nan")
    h = T975.get(len(xs) - 1, 1.96) * statistics.stdev(xs) / math.sqrt(len(xs))
    return m, m - h, m + h


def sign_test(a, b):
    """Two-sided exact binomial test of a successes against b at p = 1/2."""
    n = a + b
    if n == 0:
        return 1.0
    tail_p = sum(math.comb(n, i) for i in range(min(a, b) + 1)) / 2 ** n
    return min(1.0, 2 * tail_p)


def pct(x):
    return "n/a" if x != x else f"{100 * x:.1f}"


def training_config(base, work, checkpoint_every, validation_episodes):
    """The recipe, with checkpoints and validation when asked for (the choice of checkpoint is
    made on validation episodes on the training map only)."""
    if not checkpoint_every and not validation_episodes:
        return base
    text = open(base).read()
    if checkpoint_every:
        text, n = re.subn(r"(?m)^checkpoint_every\s*=.*$", f"checkpoint_every = {checkpoint_every}", text)
        if n == 0:
            text = text.replace("[agent.dqn]\n", f"[agent.dqn]\ncheckpoint_every = {checkpoint_every}\n", 1)
    if validation_episodes:
        if "[agent.validation]" in text:
            sys.exit(f"{base} already has [agent.validation]; leave --validation-episodes out")
        text += f"\n[agent.validation]\nepisodes = {validation_episodes}\n"
    path = os.path.join(work, "train_config.toml")
    with open(path, "w") as f:
        f.write(text)
    return path


def read_episodes(path, traffic, aggressiveness):
    """{policy: [row, ...]} in episode order."""
    out = {}
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            if r["traffic"] == traffic and float(r["aggressiveness"]) == aggressiveness:
                out.setdefault(r["policy"], []).append(r)
    for rows in out.values():
        rows.sort(key=lambda r: int(r["episode"]))
    return out


def counts(rows):
    c = {o: 0 for o in OUTCOMES}
    for r in rows:
        c[r["outcome"]] = c.get(r["outcome"], 0) + 1
    return c


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--pipeline", default="target/release/pipeline", help="the pipeline binary")
    p.add_argument("--work", default="runs/unseen_rings")
    p.add_argument("--seeds", default="0,2,3")
    p.add_argument("--config", default="configs/insertion_quick.toml", help="training recipe")
    p.add_argument("--steps", type=int, help="training transitions (default: the recipe's)")
    p.add_argument("--checkpoint-every", type=int, default=0)
    p.add_argument("--validation-episodes", type=int, default=0)
    p.add_argument("--train-map", default="data/osm/montlake_roundabout.osm.pbf")
    p.add_argument("--eval-map", default="../shared/data/osm/roundabouts/andorra.osm.pbf")
    p.add_argument("--min-ring-lanes", type=int, default=2)
    p.add_argument("--episodes", type=int, default=100, help="per ring, seed and policy")
    p.add_argument("--montlake-episodes", type=int, default=300)
    p.add_argument("--traffic", default="medium")
    p.add_argument("--aggressiveness", type=float, default=0.5)
    a = p.parse_args()
    bin_ = os.path.abspath(a.pipeline)
    seeds = [int(s) for s in a.seeds.split(",")]
    work = a.work
    os.makedirs(os.path.join(work, "logs"), exist_ok=True)
    logs = os.path.join(work, "logs")
    problems = []

    # 1. The evaluation map, imported once; its rings with two or more lanes side by side.
    andorra = os.path.join(work, "andorra_map")
    if not os.path.isfile(os.path.join(andorra, "summary.json")):
        rc, _ = run([bin_, "--rerun", "off", "map", "import", a.eval_map, "--out", andorra], f"{logs}/import.log")
        if rc:
            sys.exit(f"map import failed: {tail(f'{logs}/import.log')}")
    summary = json.load(open(os.path.join(andorra, "summary.json")))
    rings = [r for r in summary["roundabouts"] if r.get("ring_lanes", 1) >= a.min_ring_lanes]
    print(f"{len(rings)} rings with >= {a.min_ring_lanes} lanes of {len(summary['roundabouts'])}: "
          + ", ".join(f"{r['id']} ({r['kind']}, {r['ring_lanes']} lanes, r {r['radius_m']:.0f} m)" for r in rings),
          flush=True)

    # 2. One agent per seed on the training map.
    config = training_config(a.config, work, a.checkpoint_every, a.validation_episodes)
    train_s = {}
    for s in seeds:
        agent = os.path.join(work, f"agent_seed{s}")
        if not os.path.isfile(os.path.join(agent, "task.json")):
            cmd = [bin_, "--config", config, "--seed", str(s), "--rerun", "off", "agent", "train",
                   "--map", a.train_map, "--out", agent, "--traffic", a.traffic, "--record-episodes", "0"]
            if a.steps:
                cmd += ["--steps", str(a.steps)]
            rc, dt = run(cmd, f"{logs}/train_seed{s}.log")
            if rc:
                sys.exit(f"training seed {s} failed: {tail(f'{logs}/train_seed{s}.log')}")
            train_s[s] = dt
            print(f"seed {s}: trained in {dt:.0f} s", flush=True)

    # 3. Every seed on every ring and on the training map.
    evals = {}  # (seed, where) -> episodes.csv
    jobs = []
    for s in seeds:
        agent = os.path.join(work, f"agent_seed{s}")
        jobs.append((s, "montlake", agent, a.train_map, a.montlake_episodes))
        for r in rings:
            jobs.append((s, r["id"], agent, andorra, a.episodes))
    for s, where, agent, map_, episodes in jobs:
        out = os.path.join(work, "eval", f"seed{s}_{'montlake' if where == 'montlake' else f'ring{where}'}")
        csv_path = os.path.join(out, "episodes.csv")
        if not os.path.isfile(csv_path):
            log = f"{logs}/eval_{os.path.basename(out)}.log"
            ring = [] if where == "montlake" else ["--roundabout", str(where)]
            rc, dt = run([bin_, "--seed", str(s), "--rerun", "off", "agent", "eval", "--agent", agent,
                          "--map", map_, "--episodes", str(episodes), "--traffic", a.traffic,
                          "--aggressiveness", str(a.aggressiveness), "--record-episodes", "0",
                          *ring, "--out", out], log)
            if rc:
                problems.append(f"seed {s}, {where}: eval failed: {tail(log)}")
                print(problems[-1], flush=True)
                continue
            print(f"seed {s}, {where}: {episodes} episodes in {dt:.0f} s", flush=True)
        evals[(s, where)] = read_episodes(csv_path, a.traffic, a.aggressiveness)

    # 4. The tables.
    ring_ids = [r["id"] for r in rings if all((s, r["id"]) in evals for s in seeds)]
    for r in rings:
        if r["id"] not in ring_ids:
            problems.append(f"ring {r['id']} left out: not evaluated for every seed")
    lines, report = [], {"seeds": seeds, "rings": ring_ids, "episodes_per_ring": a.episodes,
                         "montlake_episodes": a.montlake_episodes, "traffic": a.traffic,
                         "aggressiveness": a.aggressiveness, "train_s": train_s, "problems": problems}

    def decided(s, w):
        """Episode indices where the ego starts before its yield line: always Not Permitted never
        enters. (On some entries of some rings the ego starts at or past the line, and every
        policy "enters" within 0.5 s: no insertion decision is left to make.)"""
        return [k for k, r in enumerate(evals[(s, w)][NOT_PERMITTED]) if not r["time_to_enter_s"]]

    def pooled(where_list, only_decided=False):
        """{policy: {seed: [rows]}} over the given places (episode k alike for every policy)."""
        by = {}
        for s in seeds:
            for w in where_list:
                keep = decided(s, w) if only_decided else range(len(evals[(s, w)][AGENT]))
                for pol, rows in evals[(s, w)].items():
                    by.setdefault(pol, {}).setdefault(s, []).extend(rows[k] for k in keep)
        return by

    def table(title, by):
        lines.append(f"\n### {title}\n")
        lines.append("| policy | reached % | crashed % | timed out % | off road % |")
        lines.append("| --- | --- | --- | --- | --- |")
        res = {}
        for pol in [AGENT] + sorted(k for k in by if k != AGENT):
            cells, res[pol] = [], {}
            for o in OUTCOMES:
                if pol == AGENT:
                    rates = [counts(by[pol][s])[o] / len(by[pol][s]) for s in seeds]
                    m, lo, hi = t_interval(rates)
                    cells.append(f"{pct(m)} ({pct(min(rates))}-{pct(max(rates))}) [{pct(max(lo, 0))}, {pct(min(hi, 1))}]")
                    res[pol][o] = {"mean": m, "per_seed": rates, "ci": [lo, hi]}
                else:
                    allrows = [r for s in seeds for r in by[pol][s]]
                    k, n = counts(allrows)[o], len(allrows)
                    lo, hi = wilson(k, n)
                    cells.append(f"{pct(k / n)} [{pct(lo)}, {pct(hi)}]")
                    res[pol][o] = {"mean": k / n, "n": n, "ci": [lo, hi]}
            name = f"**{pol}** (mean (range over seeds) [t interval])" if pol == AGENT else pol
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        return res

    def paired(title, by, res):
        base = max((p for p in res if p != AGENT), key=lambda p: res[p]["reached"]["mean"])
        lines.append(f"\n{title}: agent against the best baseline, **{base}**, episode by episode")
        diffs, d_all, only_a, only_b = [], [], 0, 0
        for s in seeds:
            ag, bs = by[AGENT][s], by[base][s]
            assert len(ag) == len(bs)
            d = [(x["outcome"] == "reached") - (y["outcome"] == "reached") for x, y in zip(ag, bs)]
            diffs.append(statistics.fmean(d))
            d_all += d
            oa, ob = d.count(-1), d.count(1)  # failed only by the agent / only by the baseline
            only_a, only_b = only_a + oa, only_b + ob
            lines.append(f"- seed {s}: reach difference {100 * diffs[-1]:+.1f} points; failed only by the agent "
                         f"{oa}, only by {base} {ob} (sign test p = {sign_test(oa, ob):.2g})")
        m, lo, hi = t_interval(diffs)
        em = statistics.fmean(d_all)
        eh = 1.96 * statistics.stdev(d_all) / math.sqrt(len(d_all))
        lines.append(f"- over seeds: {100 * m:+.1f} points (range {100 * min(diffs):+.1f} to {100 * max(diffs):+.1f}), "
                     f"95 % t interval {100 * lo:+.1f} to {100 * hi:+.1f}; over the {len(d_all)} episodes: "
                     f"{100 * (em - eh):+.1f} to {100 * (em + eh):+.1f}; failed only by the agent {only_a}, only by "
                     f"{base} {only_b}, sign test p = {sign_test(only_a, only_b):.2g}")
        return {"baseline": base, "per_seed": diffs, "t_ci": [lo, hi], "episode_ci": [em - eh, em + eh],
                "only_agent_failed": only_a, "only_baseline_failed": only_b,
                "sign_test_p": sign_test(only_a, only_b)}

    def failures(title, by, policies):
        lines.append(f"\n{title}: how the episodes end (pooled over seeds)\n")
        lines.append("| policy | crashed before / after entering | median entry lag of crashes s | timed out never "
                     "entered / entered | tight entries (< 3 s) % | median time to enter s | mean speed m/s |")
        lines.append("| --- | --- | --- | --- | --- | --- | --- |")
        out = {}
        for pol in policies:
            rows = [r for s in seeds for r in by[pol][s]]
            cr = [r for r in rows if r["outcome"] == "crashed"]
            to = [r for r in rows if r["outcome"] == "time_over"]
            lags = [float(r["entry_lag_s"]) for r in cr if r["entry_lag_s"]]
            entered = [r for r in rows if r["time_to_enter_s"]]
            all_lags = [float(r["entry_lag_s"]) for r in entered if r["entry_lag_s"]]
            tight = sum(l < 3.0 for l in all_lags) / len(entered) if entered else float("nan")
            tte = statistics.median(float(r["time_to_enter_s"]) for r in entered) if entered else float("nan")
            f = {"crash_before": sum(not r["time_to_enter_s"] for r in cr),
                 "crash_after": sum(bool(r["time_to_enter_s"]) for r in cr),
                 "crash_lag_median": statistics.median(lags) if lags else None,
                 "timeout_never_entered": sum(not r["time_to_enter_s"] for r in to),
                 "timeout_entered": sum(bool(r["time_to_enter_s"]) for r in to),
                 "tight_entry_share": tight, "time_to_enter_median": tte,
                 "mean_speed": statistics.fmean(float(r["mean_speed_mps"]) for r in rows)}
            out[pol] = f
            lag = "-" if f["crash_lag_median"] is None else f"{f['crash_lag_median']:.2f}"
            lines.append(f"| {pol} | {f['crash_before']} / {f['crash_after']} | {lag} | "
                         f"{f['timeout_never_entered']} / {f['timeout_entered']} | {pct(tight)} | {tte:.1f} | "
                         f"{f['mean_speed']:.2f} |")
        # Which baseline the agent's outcomes agree with most, episode by episode.
        agree = {}
        for pol in by:
            if pol == AGENT:
                continue
            same = sum(x["outcome"] == y["outcome"] for s in seeds for x, y in zip(by[AGENT][s], by[pol][s]))
            agree[pol] = same / sum(len(by[AGENT][s]) for s in seeds)
        lines.append("\nSame outcome as the agent, episode by episode: "
                     + ", ".join(f"{p} {pct(v)} %" for p, v in sorted(agree.items(), key=lambda kv: -kv[1])))
        out["agreement"] = agree
        return out

    lines.append(f"Seeds {seeds}; {a.traffic} traffic, aggressiveness {a.aggressiveness}; eval --seed = training seed.")
    if ring_ids:
        by = pooled(ring_ids)
        res = table(f"Two-lane rings of Andorra ({len(ring_ids)} rings x {a.episodes} episodes x {len(seeds)} seeds)", by)
        pr = paired("Andorra", by, res)
        fl = failures("Andorra", by, [AGENT, pr["baseline"], "always permitted"])
        report["andorra"] = {"table": res, "paired": pr, "failures": fl}
        by_d = pooled(ring_ids, only_decided=True)
        n_d = sum(len(by_d[AGENT][s]) for s in seeds)
        res_d = table(f"The same, only the {n_d} of {len(ring_ids) * a.episodes * len(seeds)} episodes where the ego "
                      "starts before its yield line (always not permitted never enters)", by_d)
        pr_d = paired("Andorra, episodes with a decision", by_d, res_d)
        fl_d = failures("Andorra, episodes with a decision", by_d, [AGENT, pr_d["baseline"], "always permitted"])
        report["andorra_decided"] = {"episodes": n_d, "table": res_d, "paired": pr_d, "failures": fl_d}
        # Per ring, worst first.
        lines.append("\nPer ring (reached / crashed / timed out %, agent mean over seeds):\n")
        lines.append(f"| ring | radius m | entries | no decision % | agent | agent reached per seed | {pr['baseline']} "
                     "| always permitted |")
        lines.append("| --- | --- | --- | --- | --- | --- | --- | --- |")
        per_ring = []
        for r in rings:
            if r["id"] not in ring_ids:
                continue
            def rate(pol, o, seed=None):
                rows = [x for s in seeds if seed in (None, s) for x in evals[(s, r["id"])][pol]]
                return counts(rows)[o] / len(rows)
            row = {"id": r["id"], "radius_m": r["radius_m"], "entries": r["entries"],
                   "agent": {o: rate(AGENT, o) for o in OUTCOMES},
                   "agent_reached_per_seed": [rate(AGENT, "reached", s) for s in seeds],
                   "no_decision": 1 - sum(len(decided(s, r["id"])) for s in seeds) / (a.episodes * len(seeds)),
                   "best": {o: rate(pr["baseline"], o) for o in OUTCOMES},
                   "permitted": {o: rate("always permitted", o) for o in OUTCOMES}}
            per_ring.append(row)
        per_ring.sort(key=lambda x: (x["agent"]["reached"], x["id"]))
        f3 = lambda d: f"{pct(d['reached'])} / {pct(d['crashed'])} / {pct(d['time_over'])}"
        for row in per_ring:
            lines.append(f"| {row['id']} | {row['radius_m']:.1f} | {row['entries']} | {pct(row['no_decision'])} | "
                         f"{f3(row['agent'])} | "
                         + " / ".join(pct(x) for x in row["agent_reached_per_seed"])
                         + f" | {f3(row['best'])} | {f3(row['permitted'])} |")
        report["andorra"]["per_ring"] = per_ring
    if all((s, "montlake") in evals for s in seeds):
        by = pooled(["montlake"])
        res = table(f"montlake, the training ring ({a.montlake_episodes} episodes x {len(seeds)} seeds)", by)
        pr = paired("montlake", by, res)
        fl = failures("montlake", by, [AGENT, pr["baseline"], "always permitted"])
        report["montlake"] = {"table": res, "paired": pr, "failures": fl}
    if problems:
        lines.append("\nProblems: " + "; ".join(problems))
    text = "\n".join(lines) + "\n"
    print(text)
    with open(os.path.join(work, "unseen_rings.md"), "w") as f:
        f.write(text)
    with open(os.path.join(work, "unseen_rings.json"), "w") as f:
        json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()
