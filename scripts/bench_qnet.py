#!/usr/bin/env python3
"""Times one DQN gradient step of our Q-network in burn against the same network and step in PyTorch.

The step (both sides, Double DQN): the target network and the online network on the next
observations without gradients, TD targets y = R + d * Q_target(s', argmax Q_online(s', .)),
the online network on the observations with gradients, Q of the taken actions, Huber
(smooth L1) TD loss weighted by importance weights, backward, Adam (lr 1e-4, eps 1e-8, no
gradient clipping), and the loss and TD errors copied to the host. Input: batch 32 of
[16, 84, 84] layers (4 layers x 4 frames) and 6 scalars, 3 actions; the same layer sizes
(`default`: Nature-DQN convolutions 32 8x8/4, 64 4x4/2, 64 3x3/1, flatten, a 64-wide scalar
MLP, one 256-wide hidden layer; `its`: the same convolutions, 2x2 average pool, scalars
joined directly, 256 hidden). Both use 2 threads (RAYON_NUM_THREADS=2; torch.set_num_threads(2)).

Ours is `models/examples/bench_qnet_step.rs` (release build), which calls the gradient step
training runs use (`models::dqn::Learner::learn`). The rounds alternate (ours, PyTorch,
ours, ...) so both see the same machine state; the figure is the median over all timed steps
of each side (after warm-up steps in every round).

Usage (from the repository root):
    python3 scripts/bench_qnet.py [--rounds 3] [--steps 40] [--out docs/benchmarks/qnet_step.json]
Needs: torch (CPU is enough).
"""
import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TARGET = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
BINARY = TARGET / "release" / "examples" / "bench_qnet_step"
THREADS = 2
BATCH = 32
SHAPE = (16, 84, 84)
SCALARS = 6
ACTIONS = 3


def build():
    subprocess.run(
        ["cargo", "build", "--release", "-p", "models", "--example", "bench_qnet_step"],
        cwd=ROOT,
        check=True,
    )


def ours(network, steps, warmup):
    env = dict(os.environ, RAYON_NUM_THREADS=str(THREADS))
    cmd = [str(BINARY), "--network", network, "--batch", str(BATCH), "--steps", str(steps), "--warmup", str(warmup)]
    r = subprocess.run(cmd, capture_output=True, env=env, text=True)
    if r.returncode != 0:
        sys.exit(f"failed: {' '.join(cmd)}\n{r.stderr}")
    return json.loads(r.stdout)


def torch_step_times(network, steps, warmup):
    import numpy as np
    import torch
    from torch import nn
    import torch.nn.functional as F

    torch.set_num_threads(THREADS)

    class QNet(nn.Module):
        def __init__(self, preset):
            super().__init__()
            self.convs = nn.ModuleList(
                [nn.Conv2d(SHAPE[0], 32, 8, 4), nn.Conv2d(32, 64, 4, 2), nn.Conv2d(64, 64, 3, 1)]
            )
            if preset == "default":
                self.pool = None
                self.scalar = nn.Linear(SCALARS, 64)
                merged = 64 * 7 * 7 + 64
            else:
                self.pool = nn.AdaptiveAvgPool2d((2, 2))
                self.scalar = None
                merged = 64 * 2 * 2 + SCALARS
            self.hidden = nn.Linear(merged, 256)
            self.head = nn.Linear(256, ACTIONS)

        def forward(self, layers, scalars):
            x = layers
            for conv in self.convs:
                x = F.relu(conv(x))
            if self.pool is not None:
                x = self.pool(x)
            x = x.flatten(1)
            s = F.relu(self.scalar(scalars)) if self.scalar is not None else scalars
            x = F.relu(self.hidden(torch.cat([x, s], 1)))
            return self.head(x)

    torch.manual_seed(0)
    online = QNet(network)
    target = QNet(network)
    target.load_state_dict(online.state_dict())
    opt = torch.optim.Adam(online.parameters(), lr=1e-4, eps=1e-8)
    rng = np.random.default_rng(1)

    def batch():
        layers = lambda: (rng.integers(0, 2, size=(BATCH,) + SHAPE) * 255 / 255.0).astype(np.float32)
        return dict(
            layers=layers(),
            next_layers=layers(),
            scalars=rng.integers(0, 2, size=(BATCH, SCALARS)).astype(np.float32),
            next_scalars=rng.integers(0, 2, size=(BATCH, SCALARS)).astype(np.float32),
            actions=rng.integers(0, ACTIONS, size=(BATCH, 1)).astype(np.int64),
            returns=rng.uniform(-1, 1, size=BATCH).astype(np.float32),
            discounts=np.full(BATCH, 0.99**3, dtype=np.float32),
            weights=np.ones(BATCH, dtype=np.float32),
        )

    def step(b):
        t = {k: torch.from_numpy(v) for k, v in b.items()}
        with torch.no_grad():
            next_q_target = target(t["next_layers"], t["next_scalars"])
            best = online(t["next_layers"], t["next_scalars"]).argmax(1, keepdim=True)
            y = t["returns"] + t["discounts"] * next_q_target.gather(1, best).squeeze(1)
        q = online(t["layers"], t["scalars"]).gather(1, t["actions"]).squeeze(1)
        per_sample = F.smooth_l1_loss(q, y, reduction="none")
        loss = (per_sample * t["weights"]).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        return loss.item(), (q - y).detach().numpy()

    times = []
    for i in range(warmup + steps):
        b = batch()
        start = time.perf_counter()
        step(b)
        elapsed = (time.perf_counter() - start) * 1e3
        if i >= warmup:
            times.append(elapsed)
    return times


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=40, help="timed steps per side and round")
    ap.add_argument("--warmup", type=int, default=5)
    ap.add_argument("--networks", default="default,its")
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks" / "qnet_step.json"))
    ap.add_argument("--no-build", action="store_true")
    args = ap.parse_args()
    import torch

    if not args.no_build:
        build()
    results = []
    for network in args.networks.split(","):
        ours_times, torch_times, rounds = [], [], []
        for r in range(args.rounds):
            o = ours(network, args.steps, args.warmup)
            t = torch_step_times(network, args.steps, args.warmup)
            ours_times += o["times_ms"]
            torch_times += t
            rounds.append({"ours_median_ms": statistics.median(o["times_ms"]), "torch_median_ms": statistics.median(t)})
            print(f"{network} round {r + 1}: burn {rounds[-1]['ours_median_ms']:.1f} ms, "
                  f"PyTorch {rounds[-1]['torch_median_ms']:.1f} ms", file=sys.stderr)
        ours_median = statistics.median(ours_times)
        torch_median = statistics.median(torch_times)
        results.append({
            "network": network,
            "batch": BATCH,
            "threads": THREADS,
            "timed_steps_per_side": len(ours_times),
            "burn_median_ms": round(ours_median, 2),
            "torch_median_ms": round(torch_median, 2),
            "torch_over_burn": round(torch_median / ours_median, 3),
            "rounds": rounds,
        })
        print(f"{network}: burn {ours_median:.1f} ms, PyTorch {torch_median:.1f} ms, "
              f"PyTorch/burn = {torch_median / ours_median:.2f}")
    report = {
        "what": "one DQN gradient step (Double DQN targets, Huber TD loss, backward, Adam), batch 32, 2 threads",
        "command": "python3 scripts/bench_qnet.py " + " ".join(sys.argv[1:]),
        "date": time.strftime("%Y-%m-%d"),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "load_average": os.getloadavg()},
        "torch": torch.__version__,
        "burn": "0.22.1 (flex CPU backend, simd + rayon)",
        "results": results,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
