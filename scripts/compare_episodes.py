#!/usr/bin/env python3
"""Compares two policies episode by episode from the `episodes.csv` files `agent eval` writes.

Episode k is the same traffic for every policy of one evaluation (same map, seed, condition), so
two files of evaluations with the same map, seed and episodes can be compared too.

Usage (from the repository root):
    python3 scripts/compare_episodes.py A.csv POLICY_A B.csv POLICY_B [--traffic medium --aggressiveness 0.5]
Prints the count of every (outcome under A, outcome under B) pair where either did not reach.
"""
import argparse
import collections
import csv
import sys


def load(path, policy, traffic, aggressiveness):
    rows = {}
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            if r["policy"] == policy and r["traffic"] == traffic and float(r["aggressiveness"]) == aggressiveness:
                rows[int(r["episode"])] = r["outcome"]
    if not rows:
        sys.exit(f"{path}: no episodes of policy '{policy}' at {traffic} traffic, aggressiveness {aggressiveness}")
    return rows


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file_a")
    p.add_argument("policy_a")
    p.add_argument("file_b")
    p.add_argument("policy_b")
    p.add_argument("--traffic", default="medium")
    p.add_argument("--aggressiveness", type=float, default=0.5)
    a = p.parse_args()
    left = load(a.file_a, a.policy_a, a.traffic, a.aggressiveness)
    right = load(a.file_b, a.policy_b, a.traffic, a.aggressiveness)
    if left.keys() != right.keys():
        sys.exit("the two files do not hold the same episodes")
    pairs = collections.Counter(
        (left[k], right[k]) for k in left if left[k] != "reached" or right[k] != "reached"
    )
    print(f"{a.policy_a} ({a.file_a}) against {a.policy_b} ({a.file_b}), {len(left)} episodes")
    for (x, y), n in sorted(pairs.items()):
        print(f"  {x:>10} / {y:<10} {n}")


if __name__ == "__main__":
    main()
