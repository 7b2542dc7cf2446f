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
PyTorch channels-last, ours, ...) so all see the same machine state; the figure is the median
over all timed steps of each side (after warm-up steps in every round). PyTorch runs as its
users write it and, to compare layout for layout, with the observations stored channels last
(ours on LibTorch stores convolution inputs so: models::layers).

With `--devices cpu,libtorch` ours also runs on burn's LibTorch backend (PyTorch's kernels
under burn's autodiff and optimiser), from a build with `--features libtorch` in
`$LIBTORCH_TARGET_DIR` (default target/libtorch) and the libtorch of `$LIBTORCH`
(scripts/setup_libtorch.sh; docs/gpu.md).

Usage (from the repository root):
    python3 scripts/bench_qnet.py [--rounds 3] [--steps 40] [--devices cpu[,libtorch]]
        [--out docs/benchmarks/qnet_step.json]
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
LIBTORCH_TARGET = Path(os.environ.get("LIBTORCH_TARGET_DIR", ROOT / "target" / "libtorch"))
LIBTORCH_BINARY = LIBTORCH_TARGET / "release" / "examples" / "bench_qnet_step"
THREADS = 2
BATCH = 32
SHAPE = (16, 84, 84)
SCALARS = 6
ACTIONS = 3


def build(devices):
    cmd = ["cargo", "build", "--release", "-p", "models", "--example", "bench_qnet_step"]
    subprocess.run(cmd, cwd=ROOT, check=True)
    if "libtorch" in devices:
        env = dict(os.environ, CARGO_TARGET_DIR=str(LIBTORCH_TARGET))
        subprocess.run(cmd + ["--features", "libtorch"], cwd=ROOT, check=True, env=env)


def ours(network, steps, warmup, device):
    env = dict(os.environ, RAYON_NUM_THREADS=str(THREADS))
    binary = BINARY
    if device == "libtorch":
        if "LIBTORCH" not in os.environ:
            sys.exit("--devices libtorch needs LIBTORCH set: eval \"$(scripts/setup_libtorch.sh)\"")
        binary = LIBTORCH_BINARY
        lib = str(Path(os.environ["LIBTORCH"]) / "lib")
        env["LD_LIBRARY_PATH"] = lib + ":" + env.get("LD_LIBRARY_PATH", "")
    cmd = [str(binary), "--network", network, "--batch", str(BATCH), "--steps", str(steps), "--warmup", str(warmup),
           "--device", device]
    r = subprocess.run(cmd, capture_output=True, env=env, text=True)
    if r.returncode != 0:
        sys.exit(f"failed: {' '.join(cmd)}\n{r.stderr}")
    return json.loads(r.stdout)


def torch_step_times(network, steps, warmup, channels_last=False):
    """PyTorch's step times; with `channels_last`, the observations are stored channels last
    (`torch.channels_last`, converted inside the timed step), the layout ours uses for
    convolutions on LibTorch (models::layers)."""
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
        if channels_last:
            for k in ("layers", "next_layers"):
                t[k] = t[k].contiguous(memory_format=torch.channels_last)
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
    ap.add_argument("--devices", default="cpu", help="our backends: cpu (flex) and/or libtorch")
    args = ap.parse_args()
    import torch

    devices = args.devices.split(",")
    if not args.no_build:
        build(devices)
    results = []
    for network in args.networks.split(","):
        ours_times = {d: [] for d in devices}
        torch_times, torch_cl_times, rounds = [], [], []
        for r in range(args.rounds):
            round_ = {}
            for d in devices:
                o = ours(network, args.steps, args.warmup, d)
                ours_times[d] += o["times_ms"]
                round_[f"ours_{d}_median_ms"] = statistics.median(o["times_ms"])
            t = torch_step_times(network, args.steps, args.warmup)
            torch_times += t
            round_["torch_median_ms"] = statistics.median(t)
            t = torch_step_times(network, args.steps, args.warmup, channels_last=True)
            torch_cl_times += t
            round_["torch_channels_last_median_ms"] = statistics.median(t)
            rounds.append(round_)
            print(f"{network} round {r + 1}: " + ", ".join(f"{k} {v:.1f}" for k, v in round_.items()), file=sys.stderr)
        torch_median = statistics.median(torch_times)
        result = {
            "network": network,
            "batch": BATCH,
            "threads": THREADS,
            "timed_steps_per_side": len(torch_times),
            "torch_median_ms": round(torch_median, 2),
            "torch_channels_last_median_ms": round(statistics.median(torch_cl_times), 2),
            "rounds": rounds,
        }
        for d in devices:
            # `cpu` keeps the field names of earlier reports.
            key = "burn" if d == "cpu" else f"burn_{d}"
            median = statistics.median(ours_times[d])
            result[f"{key}_median_ms"] = round(median, 2)
            result[f"torch_over_{key}"] = round(torch_median / median, 3)
            cl_median = result["torch_channels_last_median_ms"]
            result[f"torch_channels_last_over_{key}"] = round(cl_median / median, 3)
            print(f"{network}: {key} {median:.1f} ms, PyTorch {torch_median:.1f} ms, "
                  f"PyTorch/{key} = {torch_median / median:.2f}; PyTorch channels-last {cl_median:.1f} ms, "
                  f"/{key} = {cl_median / median:.2f}")
        results.append(result)
    report = {
        "what": "one DQN gradient step (Double DQN targets, Huber TD loss, backward, Adam), batch 32, 2 threads",
        "command": "python3 scripts/bench_qnet.py " + " ".join(sys.argv[1:]),
        "date": time.strftime("%Y-%m-%d"),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "load_average": os.getloadavg()},
        "torch": torch.__version__,
        "burn": "0.22.1: `burn` is the flex CPU backend (simd + rayon), `burn_libtorch` its LibTorch 2.9.0 backend",
        "results": results,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
