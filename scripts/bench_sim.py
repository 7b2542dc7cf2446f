#!/usr/bin/env python3
"""Roundabout-insertion throughput against highway-env roundabout-v0, in one run.

Both sides: policy steps per CPU-second, a random policy, the same number of steps,
episodes reset inside the timed loop.
- Ours: `sim/examples/bench_insertion.rs` (built here with `cargo build --release`) on the
  bundled montlake_roundabout map, high traffic (at most 8 other vehicles; arrivals at
  10/s so the cap holds nearly all the time: the mean count is in the output), the
  4 × 84 × 84 bird's-eye observation rendered at every 0.1 s step. CPU time of the stepping
  thread from /proc/thread-self/schedstat, setup (map import, raster) excluded.
- highway-env: `gymnasium.make("roundabout-v0")` with its GrayscaleObservation at 84 × 84,
  stack 4 (the configuration of its documentation), everything else default (policy
  frequency 1 Hz, simulation 15 Hz); CPU time of this process (time.process_time) around
  the stepping loop. Also reported, not in the headline ratio: the same with
  policy_frequency 10 (one policy step per 0.1 s, like ours).

Usage (from the repository root; needs `pip install highway-env`):
    python3 scripts/bench_sim.py [--steps 3000] [--long-steps 100000]
Writes docs/benchmarks/sim_throughput.json and prints a markdown row set for docs/benchmarks.md.
"""
import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TARGET = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
BIN = TARGET / "release" / "examples" / "bench_insertion"


def ours(steps, seed=0, world=None):
    out = subprocess.run(
        [str(BIN), "--steps", str(steps), "--traffic", "high", "--policy", "random", "--seed", str(seed),
         "--arrivals-per-s", "10"] + (["--world", world] if world else []),
        cwd=ROOT, capture_output=True, text=True,
    )
    if out.returncode != 0:
        sys.exit(f"bench_insertion failed: {out.stderr}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def highway(steps, policy_frequency=None, seed=0):
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    import gymnasium as gym
    import highway_env  # noqa: F401  (registers the environments)
    import numpy as np

    config = {"observation": {"type": "GrayscaleObservation", "observation_shape": (84, 84), "stack_size": 4,
                              "weights": [0.2989, 0.5870, 0.1140], "scaling": 1.75}}
    if policy_frequency is not None:
        config["policy_frequency"] = policy_frequency
    env = gym.make("roundabout-v0", config=config)
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    others, episodes = 0, 1
    cpu0, wall0 = time.process_time(), time.perf_counter()
    for _ in range(steps):
        obs, _, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
        others += len(env.unwrapped.road.vehicles) - 1
        if terminated or truncated:
            obs, _ = env.reset()
            episodes += 1
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    cfg = env.unwrapped.config
    return {"steps": steps, "episodes": episodes, "cpu_s": cpu, "wall_s": wall, "steps_per_cpu_s": steps / cpu,
            "mean_other_vehicles": others / steps, "observation_shape": list(obs.shape),
            "policy_frequency": cfg["policy_frequency"], "simulation_frequency": cfg["simulation_frequency"]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=3000, help="steps for both sides (the ratio)")
    ap.add_argument("--long-steps", type=int, default=100000, help="a longer run of ours alone")
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks" / "sim_throughput.json"))
    ap.add_argument("--world", default=str(ROOT / "configs" / "traffic_interaction_ft.toml"),
                    help="a calibration: ours is also timed in its world (high traffic at 0.9 of entry capacity)")
    args = ap.parse_args()
    subprocess.run(["cargo", "build", "--release", "-q", "-p", "sim", "--example", "bench_insertion"], cwd=ROOT, check=True)
    import highway_env
    ours_same = ours(args.steps)
    hw_default = highway(args.steps)
    hw_10hz = highway(args.steps, policy_frequency=10)
    ours_long = ours(args.long_steps)
    ours_calibrated = ours(args.long_steps, world=args.world)
    ratio = ours_same["steps_per_cpu_s"] / hw_default["steps_per_cpu_s"]
    result = {
        "date": time.strftime("%Y-%m-%d"),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
        "highway_env_version": getattr(highway_env, "__version__", "unknown"),
        "ours": ours_same, "ours_long": ours_long, "ours_calibrated_long": ours_calibrated,
        "highway_env_roundabout_v0": hw_default, "highway_env_roundabout_v0_10hz": hw_10hz,
        "ratio_ours_over_highway_env": ratio,
        "ratio_ours_over_highway_env_10hz": ours_same["steps_per_cpu_s"] / hw_10hz["steps_per_cpu_s"],
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"| ours, {args.steps} steps | {ours_same['steps_per_cpu_s']:,.0f} | {ours_same['mean_other_vehicles']:.1f} |")
    print(f"| ours, {args.long_steps} steps | {ours_long['steps_per_cpu_s']:,.0f} | {ours_long['mean_other_vehicles']:.1f} |")
    print(f"| ours in the calibrated world, {args.long_steps} steps | {ours_calibrated['steps_per_cpu_s']:,.0f} | {ours_calibrated['mean_other_vehicles']:.1f} |")
    print(f"| highway-env roundabout-v0 (1 Hz policy), {args.steps} steps | {hw_default['steps_per_cpu_s']:,.1f} | {hw_default['mean_other_vehicles']:.1f} |")
    print(f"| highway-env roundabout-v0 at 10 Hz policy, {args.steps} steps | {hw_10hz['steps_per_cpu_s']:,.1f} | {hw_10hz['mean_other_vehicles']:.1f} |")
    print(f"ratio ours / highway-env: {ratio:,.0f}x (10 Hz: {result['ratio_ours_over_highway_env_10hz']:,.0f}x)")


if __name__ == "__main__":
    main()
