#!/usr/bin/env python3
"""Times the burn segmenter against the same network in PyTorch on the CPU, in one run.

Both sides build the default architecture (ResNet-18 basic blocks, width 1, depth 3 =
output stride 8, pyramid bins 1, 2, 3, 6, 512 pyramid channels, 5 classes; or the options
given) with untrained weights, and time with the same protocol: WARMUP untimed runs, then
RUNS timed ones, median; fixed pseudo-random inputs. The sides take turns for ROUNDS rounds
(ours, ours on LibTorch, PyTorch, PyTorch channels-last, ours, ...) so that all see the same
state of the machine; each figure is the median of a side's round medians.

PyTorch runs twice: as its users write it (tensors in its default NCHW layout) and with the
model and inputs in `torch.channels_last`, the layout ours uses on LibTorch when training
(models::layers); the report gives the ratio against both.

- inference: one forward pass at SIZE x SIZE, batch 1, THREADS threads (burn: a rayon pool
  of THREADS threads; PyTorch: torch.set_num_threads(THREADS), eval mode, no_grad);
- training step: forward, cross-entropy, backward and an Adam step (lr 1e-4) at batch
  TRAIN_BATCH, training mode (batch-norm statistics, dropout), same threads.

Ours is `pipeline segmenter bench --json` (release build); PyTorch's network is the
PspNet class of scripts/segmenter_reference.py (the module the numerics test checks burn
against), so both run the same layers.

With `--libtorch-pipeline PATH` (a build with `--features libtorch`, run with the libtorch of
`$LIBTORCH`: scripts/setup_libtorch.sh, docs/gpu.md) ours is also timed on burn's LibTorch
backend in the same run: PyTorch's kernels under burn's layers, autodiff and Adam.

With `--bf16` (needs `--libtorch-pipeline`), two more sides: ours on LibTorch with
`--bf16-convolutions` (the convolutions in bfloat16, everything else f32) and PyTorch
channels-last with its CPU autocast to bfloat16 (`torch.autocast("cpu", torch.bfloat16)`, the
way its users ask for bfloat16: convolutions and matrix products in bfloat16, and the layers
between them on bfloat16 activations). Training steps only; inference stays f32.

Usage (from the repository root; installs torch from PyPI when missing):
    cargo build --release -p pipeline
    python3 scripts/bench_segmenter.py [--rounds 3] [--runs 20] [--threads 2] [--size 256]
        [--pipeline target/release/pipeline] [--libtorch-pipeline target/libtorch/release/pipeline]
        [--bf16] [--out docs/benchmarks/segmenter.json] [-- extra bench options]
"""
import argparse
import importlib.util
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def load_reference():
    spec = importlib.util.spec_from_file_location("segmenter_reference", ROOT / "scripts" / "segmenter_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # installs torch and safetensors when missing
    return module


def ours(args, extra, pipeline=None, device="cpu"):
    env = dict(os.environ)
    if device == "libtorch":
        if "LIBTORCH" not in env:
            sys.exit("--libtorch-pipeline needs LIBTORCH set: eval \"$(scripts/setup_libtorch.sh)\"")
        env["LD_LIBRARY_PATH"] = str(Path(env["LIBTORCH"]) / "lib") + ":" + env.get("LD_LIBRARY_PATH", "")
    cmd = [pipeline or args.pipeline, "-q", "--device", device, "--rerun", "off", "segmenter", "bench", "--json",
           "--size", str(args.size), "--batch", "1", "--threads", str(args.threads),
           "--iterations", str(args.runs), "--warmup", str(args.warmup),
           "--train-steps", str(args.train_runs), "--train-batch", str(args.train_batch)] + extra
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if r.returncode != 0:
        sys.exit(f"failed ({r.returncode}): {' '.join(cmd)}\n{r.stderr}")
    return json.loads(r.stdout), cmd


def median_ms(fn, warmup, runs):
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1000.0)
    return statistics.median(times), min(times), max(times)


def across_rounds(figures):
    """A side's figures over the rounds: the last round's record, with each timing replaced by
    the median of the round medians (and the round medians kept)."""
    combined = dict(figures[-1])
    for key in ("inference_ms", "train_step_ms"):
        medians = [f[key]["median"] for f in figures]
        combined[key] = {"median": statistics.median(medians), "round_medians": medians,
                         "min": min(f[key]["min"] for f in figures), "max": max(f[key]["max"] for f in figures),
                         "runs_per_round": figures[-1][key]["runs"]}
    return combined


def pytorch(args, ref, config, channels_last=False, autocast_bf16=False):
    """PyTorch's figures; with `channels_last`, the weights and inputs stored channels last
    (`torch.channels_last`), the layout in which its CPU convolutions run fastest and the one
    ours uses on LibTorch when training (models::layers); with `autocast_bf16`, the training
    step's forward pass under CPU autocast to bfloat16."""
    import torch
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    cfg = dict(config)
    model = ref.PspNet(cfg)
    params = sum(p.numel() for p in model.parameters())
    # burn counts the batch-norm running statistics with the parameters; PyTorch keeps them
    # as buffers. Both figures are reported; the networks must agree on the total.
    running_stats = sum(b.numel() for n, b in model.named_buffers()
                        if n.endswith("running_mean") or n.endswith("running_var"))
    x = torch.randn(1, 3, args.size, args.size)
    layout = torch.channels_last if channels_last else torch.contiguous_format
    model = model.to(memory_format=layout)
    x = x.contiguous(memory_format=layout)

    model.eval()
    with torch.no_grad():
        inf = median_ms(lambda: model(x), args.warmup, args.runs)

    model.train()
    xb = torch.randn(args.train_batch, 3, args.size, args.size)
    xb = xb.contiguous(memory_format=layout)
    yb = torch.randint(0, cfg["classes"], (args.train_batch, args.size, args.size))
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    loss_fn = torch.nn.CrossEntropyLoss(ignore_index=255)
    drop = torch.nn.Dropout2d(cfg["dropout"])

    def step():
        opt.zero_grad(set_to_none=True)
        h, w = xb.shape[2:]
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast_bf16):
            logits = torch.nn.functional.interpolate(model.head(xb, drop), size=(h, w), mode="bilinear",
                                                     align_corners=cfg["align_corners"])
        loss_fn(logits.float(), yb).backward()
        opt.step()

    train = median_ms(step, min(args.warmup, 1), args.train_runs)
    return {"torch": torch.__version__, "channels_last": channels_last, "autocast_bf16": autocast_bf16,
            "parameters": params,
            "parameters_with_running_stats": params + running_stats,
            "inference_ms": {"median": inf[0], "min": inf[1], "max": inf[2], "runs": args.runs},
            "train_step_ms": {"median": train[0], "min": train[1], "max": train[2], "runs": args.train_runs}}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=3, help="turns each side takes")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--train-runs", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--train-batch", type=int, default=8)
    default_bin = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target")) / "release" / "pipeline"
    ap.add_argument("--pipeline", default=str(default_bin))
    ap.add_argument("--libtorch-pipeline", help="also time ours on burn's LibTorch backend with this build")
    ap.add_argument("--bf16", action="store_true",
                    help="also time training steps with bfloat16 convolutions (ours) and autocast (PyTorch)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks" / "segmenter.json"))
    args, extra = ap.parse_known_args()
    extra = [e for e in extra if e != "--"]
    if args.bf16 and not args.libtorch_pipeline:
        sys.exit("--bf16 needs --libtorch-pipeline: bfloat16 convolutions run on the LibTorch backend only")
    if not Path(args.pipeline).exists():
        sys.exit(f"{args.pipeline} not found: cargo build --release -p pipeline (or give --pipeline)")
    ref = load_reference()
    rounds = {"burn": [], "pytorch": [], "burn_libtorch": [], "pytorch_channels_last": [],
              "burn_libtorch_bf16": [], "pytorch_channels_last_bf16": []}
    for round_index in range(args.rounds):
        burn, cmd = ours(args, extra)
        rounds["burn"].append(burn)
        if args.libtorch_pipeline:
            on_libtorch, libtorch_cmd = ours(args, extra, args.libtorch_pipeline, "libtorch")
            rounds["burn_libtorch"].append(on_libtorch)
        rounds["pytorch"].append(pytorch(args, ref, burn["config"]))
        rounds["pytorch_channels_last"].append(pytorch(args, ref, burn["config"], channels_last=True))
        if args.bf16:
            bf16, bf16_cmd = ours(args, extra + ["--bf16-convolutions"], args.libtorch_pipeline, "libtorch")
            rounds["burn_libtorch_bf16"].append(bf16)
            rounds["pytorch_channels_last_bf16"].append(
                pytorch(args, ref, burn["config"], channels_last=True, autocast_bf16=True))
        print(f"round {round_index + 1}: training step "
              + ", ".join(f"{side} {figures[-1]['train_step_ms']['median']:.0f} ms"
                          for side, figures in rounds.items() if figures), file=sys.stderr)
    burn = across_rounds(rounds["burn"])
    torch_figures = across_rounds(rounds["pytorch"])
    torch_cl = across_rounds(rounds["pytorch_channels_last"])
    if torch_figures["parameters_with_running_stats"] != burn["parameters"]:
        sys.exit(f"not the same network: {burn['parameters']} parameters and batch-norm statistics "
                 f"in burn, {torch_figures['parameters_with_running_stats']} in PyTorch")
    b_inf, t_inf = burn["inference_ms"]["median"], torch_figures["inference_ms"]["median"]
    b_tr, t_tr = burn["train_step_ms"]["median"], torch_figures["train_step_ms"]["median"]
    result = {
        "date": time.strftime("%Y-%m-%d"), "machine": platform.processor() or platform.machine(),
        "command": " ".join(map(str, cmd)), "size": args.size, "threads": args.threads,
        "train_batch": args.train_batch, "rounds": args.rounds, "burn": burn, "pytorch": torch_figures,
        "pytorch_channels_last": torch_cl,
        "inference_ratio_torch_over_burn": t_inf / b_inf, "train_step_ratio_torch_over_burn": t_tr / b_tr,
    }
    sides = [("burn (flex)", burn)]
    if args.libtorch_pipeline:
        on_libtorch = across_rounds(rounds["burn_libtorch"])
        result["burn_libtorch"] = on_libtorch
        result["libtorch_command"] = " ".join(map(str, libtorch_cmd))
        result["inference_ratio_torch_over_burn_libtorch"] = t_inf / on_libtorch["inference_ms"]["median"]
        result["train_step_ratio_torch_over_burn_libtorch"] = t_tr / on_libtorch["train_step_ms"]["median"]
        result["train_step_ratio_torch_channels_last_over_burn_libtorch"] = (
            torch_cl["train_step_ms"]["median"] / on_libtorch["train_step_ms"]["median"])
        sides.append(("burn (LibTorch)", on_libtorch))
    if args.bf16:
        ours_bf16 = across_rounds(rounds["burn_libtorch_bf16"])
        torch_bf16 = across_rounds(rounds["pytorch_channels_last_bf16"])
        result.update({
            "burn_libtorch_bf16": ours_bf16, "bf16_command": " ".join(map(str, bf16_cmd)),
            "pytorch_channels_last_bf16": torch_bf16,
            "train_step_ratio_torch_bf16_over_burn_libtorch_bf16": (
                torch_bf16["train_step_ms"]["median"] / ours_bf16["train_step_ms"]["median"]),
        })
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"network: {burn['parameters']} parameters, {burn['gflops_per_image']:.2f} GFLOPs per {args.size}x{args.size} image")
    names = [name for name, _ in sides]
    peers = [("PyTorch", torch_figures), ("PyTorch channels-last", torch_cl)]
    print("| measurement | " + " | ".join(f"{n} ms" for n in names + [p for p, _ in peers]) + " | "
          + " | ".join(f"{p} / {n}" for p, _ in peers for n in names) + " |")
    print("| --- |" + " ---: |" * (len(sides) + len(peers) + len(sides) * len(peers)))
    rows = [
        (f"inference {args.size}x{args.size}, batch 1, {args.threads} threads "
         f"(median of {args.rounds} rounds of {args.runs})", "inference_ms", ".1f"),
        (f"training step, batch {args.train_batch}, {args.threads} threads "
         f"(median of {args.rounds} rounds of {args.train_runs})", "train_step_ms", ".0f"),
    ]
    for label, key, fmt in rows:
        mine = [side[key]["median"] for _, side in sides]
        theirs = [peer[key]["median"] for _, peer in peers]
        print(f"| {label} | " + " | ".join(format(v, fmt) for v in mine + theirs) + " | "
              + " | ".join(f"{t / m:.2f}" for t in theirs for m in mine) + " |")
    if args.bf16:
        mine, theirs = ours_bf16["train_step_ms"]["median"], torch_bf16["train_step_ms"]["median"]
        print(f"| training step in bfloat16 (ours: --bf16-convolutions on LibTorch; PyTorch: channels-last, "
              f"CPU autocast) | {mine:.0f} | {theirs:.0f} | PyTorch / ours {theirs / mine:.2f} |")
    print(f"PyTorch {torch_figures['torch']}; raw figures in {args.out}")


if __name__ == "__main__":
    main()
