#!/usr/bin/env python3
"""What the resolution of a segmenter's head alone costs in IoU, per class.

A PSPNet-style head predicts on a grid coarser than the image (stride 4 or 8 of the network's input) and
upsamples its logits bilinearly. This script takes the labels of a dataset split, averages their one-hot
planes down to an N x N grid (what a perfect head at that resolution could hold), upsamples them bilinearly
back (align_corners, as the segmenter does), takes the argmax and scores it against the labels. The result
is the IoU of a network that is right everywhere except for what its grid cannot draw: an upper bound for a
head of that resolution (docs/segmenter.md).

    python3 scripts/segmenter_head_ceiling.py runs/gen2000 [--split val] [--grids 128,96,64,48] [--out FILE]

A grid of 96 is stride 4 of a 384-px input, 64 stride 4 of 256 px, 128 stride 2 of 256 px. Installs PyTorch
and Pillow with pip when they are missing.
"""

import argparse
import json
import os
import subprocess
import sys

CLASSES = ["road", "lane_marking", "vehicle", "human", "other"]
IGNORE = 255


def ensure(module, package):
    try:
        __import__(module)
    except ImportError:
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", package], check=True)


def read_labels(dataset, split):
    import numpy as np
    from PIL import Image

    with open(os.path.join(dataset, "manifest.jsonl")) as f:
        entries = [json.loads(line) for line in f if line.strip()]
    labels = [
        np.array(Image.open(os.path.join(dataset, e["label"])))
        for e in entries
        if e.get("split") == split
    ]
    if not labels:
        sys.exit(f"{dataset}: no images in split {split!r} (run `pipeline dataset split` first)")
    return np.stack(labels)


def ceiling(labels, grid, batch=50):
    import numpy as np
    import torch
    import torch.nn.functional as F

    y = torch.from_numpy(labels).long()
    valid = y != IGNORE
    inter = np.zeros(len(CLASSES))
    union = np.zeros(len(CLASSES))
    for i in range(0, len(y), batch):
        t = y[i : i + batch]
        v = valid[i : i + batch]
        one_hot = F.one_hot(t.clamp(max=len(CLASSES) - 1), len(CLASSES)).permute(0, 3, 1, 2).float()
        one_hot = one_hot * v.unsqueeze(1)
        coarse = F.adaptive_avg_pool2d(one_hot, grid)
        back = F.interpolate(coarse, size=t.shape[-2:], mode="bilinear", align_corners=True)
        p = back.argmax(1)
        for c in range(len(CLASSES)):
            inter[c] += ((p == c) & (t == c) & v).sum().item()
            union[c] += (((p == c) | (t == c)) & v).sum().item()
    present = union > 0
    iou = {CLASSES[c]: inter[c] / union[c] for c in range(len(CLASSES)) if present[c]}
    return {"grid": grid, "miou": float(np.mean(list(iou.values()))), "per_class_iou": iou}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", help="a dataset folder (manifest.jsonl, labels/)")
    ap.add_argument("--split", default="val")
    ap.add_argument("--grids", default="128,96,64,48", help="head grid sides to score")
    ap.add_argument("--out", help="write the figures as JSON here")
    args = ap.parse_args()
    ensure("torch", "torch")
    ensure("PIL", "pillow")
    labels = read_labels(args.dataset, args.split)
    rows = [ceiling(labels, int(g)) for g in args.grids.split(",")]
    print(f"{len(labels)} labels of {args.dataset} ({args.split}), {labels.shape[1]} x {labels.shape[2]} px")
    print("grid | mIoU | " + " | ".join(CLASSES))
    for r in rows:
        cells = " | ".join(f"{r['per_class_iou'].get(c, float('nan')):.3f}" for c in CLASSES)
        print(f"{r['grid']} | {r['miou']:.3f} | {cells}")
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"dataset": args.dataset, "split": args.split, "images": len(labels), "rows": rows}, f, indent=2)


if __name__ == "__main__":
    main()
