#!/usr/bin/env python3
"""Reference outputs for the segmenter's numerics test (models/tests/segmenter_reference.rs).

Builds small networks of the same architecture as models/src/segmenter/model.rs in PyTorch
(module names equal to the burn field names), fills them with fixed weights from a seeded
torch generator, runs a fixed input in eval mode and stores, under models/tests/data/:

  segmenter_reference.json                 the PspNetConfig of each network
  segmenter_reference_<name>.safetensors   its weights (PyTorch names: BatchNorm weight/bias)
  segmenter_reference_io.safetensors       <name>.input and <name>.output of each network

The Rust test `segmenter_reference_outputs_match_pytorch` (models/tests/segmenter_reference.rs)
loads the weights into the burn model and checks the outputs within 1e-4.

Usage: python3 scripts/segmenter_reference.py   (installs torch and safetensors from PyPI
if missing; CPU only, a few seconds)
"""

import json
import math
import os
import subprocess
import sys


def ensure(package, module=None):
    try:
        __import__(module or package)
    except ImportError:
        subprocess.check_call([sys.executable, "-m", "pip", "install", "-q", package])


ensure("torch")
ensure("safetensors")

import torch  # noqa: E402
import torch.nn as nn  # noqa: E402
import torch.nn.functional as F  # noqa: E402
from safetensors.torch import save_file  # noqa: E402

RESNET_WIDTHS = [64, 64, 128, 256, 512]
OUT_DIR = os.path.join(os.path.dirname(__file__), "..", "models", "tests", "data")

# Two small networks covering both code paths: smp's default shape (depth 3, no skip,
# aligned corners) and the options (depth 4 dilated, skip refinement, half-pixel resize).
# Kept small: all files together stay under 200 KB.
CONFIGS = {
    "a": dict(classes=5, blocks=[2, 2, 1, 1], width=0.125, depth=3, dilated=False,
              bins=[1, 2, 3, 6], psp_channels=16, dropout=0.2, skip_channels=0,
              aux_head=False, align_corners=True,
              mean=[123.675, 116.28, 103.53], std=[58.395, 57.12, 57.375]),
    "b": dict(classes=5, blocks=[1, 1, 2, 1], width=0.0625, depth=4, dilated=True,
              bins=[1, 2, 3, 6], psp_channels=12, dropout=0.2, skip_channels=6,
              aux_head=False, align_corners=False,
              mean=[123.675, 116.28, 103.53], std=[58.395, 57.12, 57.375]),
}
INPUT_SIZES = {"a": (1, 3, 32, 32), "b": (1, 3, 24, 40)}


def widths(cfg):
    return [max(1, round(c * cfg["width"])) for c in RESNET_WIDTHS]


class ConvNorm(nn.Module):
    def __init__(self, cin, cout, k, stride=1, dilation=1, norm=True):
        super().__init__()
        pad = k // 2 * dilation
        self.conv = nn.Conv2d(cin, cout, k, stride, pad, dilation, bias=not norm)
        self.norm = nn.BatchNorm2d(cout) if norm else None

    def forward(self, x):
        x = self.conv(x)
        return self.norm(x) if self.norm is not None else x


class BasicBlock(nn.Module):
    def __init__(self, cin, cout, stride, dilation):
        super().__init__()
        self.conv1 = ConvNorm(cin, cout, 3, stride, dilation)
        self.conv2 = ConvNorm(cout, cout, 3, 1, dilation)
        self.downsample = ConvNorm(cin, cout, 1, stride) if stride != 1 or cin != cout else None

    def forward(self, x):
        shortcut = self.downsample(x) if self.downsample is not None else x
        return F.relu(self.conv2(F.relu(self.conv1(x))) + shortcut)


class Stage(nn.Module):
    def __init__(self, blocks):
        super().__init__()
        self.blocks = nn.ModuleList(blocks)

    def forward(self, x):
        for b in self.blocks:
            x = b(x)
        return x


def stage_geometry(cfg, i):
    if i == 0:
        return 1, 1
    if i == 1:
        return 2, 1
    if cfg["dilated"]:
        return 1, 2 if i == 2 else 4
    return 2, 1


class Encoder(nn.Module):
    def __init__(self, cfg):
        super().__init__()
        w = widths(cfg)
        self.stem = ConvNorm(3, w[0], 7, 2)
        self.pool = nn.MaxPool2d(3, 2, 1)
        stages = []
        for s in range(cfg["depth"] - 1):
            stride, dilation = stage_geometry(cfg, s)
            blocks = [BasicBlock(w[s] if b == 0 else w[s + 1], w[s + 1], stride if b == 0 else 1, dilation)
                      for b in range(cfg["blocks"][s])]
            stages.append(Stage(blocks))
        self.stages = nn.ModuleList(stages)

    def forward(self, x):
        """The stem's output (stride 2, before the max-pool) and every stage's."""
        stem = F.relu(self.stem(x))
        x = self.pool(stem)
        outs = []
        for s in self.stages:
            x = s(x)
            outs.append(x)
        return stem, outs


class PoolBranch(nn.Module):
    def __init__(self, bin, cin, cout):
        super().__init__()
        self.bin = bin
        self.conv = ConvNorm(cin, cout, 1, norm=bin != 1)


class PyramidPooling(nn.Module):
    def __init__(self, cfg, features):
        super().__init__()
        branch = max(1, features // len(cfg["bins"]))
        self.branches = nn.ModuleList([PoolBranch(b, features, branch) for b in cfg["bins"]])
        self.bottleneck = ConvNorm(features + branch * len(cfg["bins"]), cfg["psp_channels"], 1)
        self.align_corners = cfg["align_corners"]

    def forward(self, x):
        h, w = x.shape[2:]
        parts = [F.interpolate(F.relu(b.conv(F.adaptive_avg_pool2d(x, b.bin))), size=(h, w),
                               mode="bilinear", align_corners=self.align_corners)
                 for b in self.branches]
        return F.relu(self.bottleneck(torch.cat(parts + [x], 1)))


class SkipRefinement(nn.Module):
    def __init__(self, low, high, channels, align_corners):
        super().__init__()
        self.low = ConvNorm(low, channels, 1)
        self.high = ConvNorm(high, channels, 1)
        self.fuse = ConvNorm(2 * channels, channels, 3)
        self.align_corners = align_corners

    def forward(self, high, low):
        h, w = low.shape[2:]
        high = F.interpolate(F.relu(self.high(high)), size=(h, w), mode="bilinear",
                             align_corners=self.align_corners)
        return F.relu(self.fuse(torch.cat([high, F.relu(self.low(low))], 1)))


class PspNet(nn.Module):
    def __init__(self, cfg):
        super().__init__()
        w = widths(cfg)
        self.cfg = cfg
        self.encoder = Encoder(cfg)
        self.pyramid = PyramidPooling(cfg, w[cfg["depth"] - 1])
        mid = cfg.get("mid_skip_channels", 0)
        # The stride-8 refinement on stage 2's output (burn's `mid_skip`), depth 4 and 5.
        self.mid_skip = SkipRefinement(w[2], cfg["psp_channels"], mid, cfg["align_corners"]) if mid > 0 else None
        high = mid or cfg["psp_channels"]
        self.skip = SkipRefinement(w[1], high, cfg["skip_channels"], cfg["align_corners"]) \
            if cfg["skip_channels"] > 0 else None
        coarse = cfg["skip_channels"] or high
        fine = cfg.get("fine_skip_channels", 0)
        # The stride-2 refinement on the stem's output (burn's `fine_skip`).
        self.fine_skip = SkipRefinement(w[0], coarse, fine, cfg["align_corners"]) if fine > 0 else None
        self.classifier = nn.Conv2d(fine or coarse, cfg["classes"], 1)

    def head(self, x, dropout=None):
        """The logits at the head's resolution; `dropout` (a module) after the pyramid, in training."""
        stem, stages = self.encoder(x)
        y = self.pyramid(stages[-1])
        if dropout is not None:
            y = dropout(y)
        if self.mid_skip is not None:
            y = self.mid_skip(y, stages[1])
        if self.skip is not None:
            y = self.skip(y, stages[0])
        if self.fine_skip is not None:
            y = self.fine_skip(y, stem)
        return self.classifier(y)

    def forward(self, x):
        h, w = x.shape[2:]
        return F.interpolate(self.head(x), size=(h, w), mode="bilinear",
                             align_corners=self.cfg["align_corners"])


def fill(model, gen):
    """Fixed, non-trivial weights: everything drawn from `gen`, BatchNorm statistics included."""
    with torch.no_grad():
        for name, module in model.named_modules():
            if isinstance(module, nn.Conv2d):
                fan_in = module.weight[0].numel()
                module.weight.copy_(torch.randn(module.weight.shape, generator=gen) * math.sqrt(2.0 / fan_in))
                if module.bias is not None:
                    module.bias.copy_(torch.randn(module.bias.shape, generator=gen) * 0.1)
            elif isinstance(module, nn.BatchNorm2d):
                n = module.num_features
                module.weight.copy_(0.5 + torch.rand(n, generator=gen))
                module.bias.copy_(torch.randn(n, generator=gen) * 0.1)
                module.running_mean.copy_(torch.randn(n, generator=gen) * 0.1)
                module.running_var.copy_(0.5 + torch.rand(n, generator=gen))


def main():
    torch.set_num_threads(1)
    os.makedirs(OUT_DIR, exist_ok=True)
    io = {}
    for name, cfg in CONFIGS.items():
        gen = torch.Generator().manual_seed(1234 + ord(name))
        model = PspNet(cfg).eval()
        fill(model, gen)
        x = torch.randn(INPUT_SIZES[name], generator=gen)
        with torch.no_grad():
            y = model(x)
        weights = {k: v.contiguous() for k, v in model.state_dict().items()
                   if not k.endswith("num_batches_tracked")}
        save_file(weights, os.path.join(OUT_DIR, f"segmenter_reference_{name}.safetensors"))
        io[f"{name}.input"] = x.contiguous()
        io[f"{name}.output"] = y.contiguous()
        print(f"{name}: {sum(v.numel() for v in weights.values())} weights, output {tuple(y.shape)}, "
              f"mean {y.mean():.6f} std {y.std():.6f}")
    save_file(io, os.path.join(OUT_DIR, "segmenter_reference_io.safetensors"))
    with open(os.path.join(OUT_DIR, "segmenter_reference.json"), "w") as f:
        json.dump(CONFIGS, f, indent=2, sort_keys=True)
        f.write("\n")


if __name__ == "__main__":
    main()
