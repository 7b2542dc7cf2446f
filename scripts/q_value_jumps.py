#!/usr/bin/env python3
"""How much an insertion agent's Q-values move from one 0.1 s decision to the next on the approach.

For each agent, drives evaluation episodes 0 .. N-1 with `agent_episode_trace` (deciding every 0.1 s,
aggressiveness 0.5, medium traffic, the evaluation's seed 0) and collects, for every decision whose
ego is 0 to 10 m before its yield line, the largest change of any action's Q-value since the decision
before. Prints the distribution per agent.

    cargo build --release -p pipeline --example agent_episode_trace
    python3 scripts/q_value_jumps.py --episodes 500 runs/insertion_fine_convs_s0 runs/insertion_antialias_s0
"""

import argparse
import re
import subprocess
import sys

DECISION = re.compile(r"decision +\d+ t +[\d.]+ Q \[([^\]]*)\].*to yield +(-?[\d.]+)")


def approach_jumps(trace: str, agent: str, episode: int) -> list[float]:
    run = subprocess.run([trace, agent, str(episode)], capture_output=True, text=True)
    if run.returncode != 0:
        sys.exit(f"{trace} {agent} {episode} failed: {run.stderr.strip()}")
    decisions = []
    for line in run.stdout.splitlines():
        m = DECISION.match(line)
        if m:
            q = [float(x) for x in m.group(1).split(",")]
            decisions.append((float(m.group(2)), q))
    return [
        max(abs(a - b) for a, b in zip(q1, q0))
        for (_, q0), (to_line, q1) in zip(decisions, decisions[1:])
        if 0.0 <= to_line <= 10.0
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("agents", nargs="+", help="trained agent folders")
    parser.add_argument("--episodes", type=int, default=500)
    parser.add_argument("--trace", default="target/release/examples/agent_episode_trace")
    args = parser.parse_args()
    for agent in args.agents:
        jumps = sorted(j for e in range(args.episodes) for j in approach_jumps(args.trace, agent, e))
        if not jumps:
            print(f"{agent}: no decision 0-10 m before a line")
            continue
        n = len(jumps)
        pct = lambda p: jumps[min(n - 1, int(n * p))]  # noqa: E731
        over = sum(j > 0.5 for j in jumps)
        print(
            f"{agent}: {n} decisions 0-10 m before the line; change of a Q-value since the decision before: "
            f"median {pct(0.5):.3f}, 90th percentile {pct(0.9):.3f}, 99th {pct(0.99):.3f}, "
            f"max {jumps[-1]:.3f}; above 0.5 in {over} ({over / n * 100:.2f} %)"
        )


if __name__ == "__main__":
    main()
