#!/usr/bin/env python3
"""Which objects of one class a segmenter misses, by their size in the image.

Each connected blob of the class in the labels (4-connected) is put in a size bin by its pixel count; per bin the
script reports the blobs, their pixels and how many of those pixels the predictions give the class (recall). It
also reports the pixels predicted as the class outside any blob (false), the class IoU, and what the IoU would be
if every blob of at least --small pixels were found whole (the false pixels unchanged): how much of the loss the
small, far objects explain and how much the rest (docs/segmenter.md). Last, how many of the missed and of the false
pixels lie on the class's outline (within one pixel of a label edge of the class, 8-connected): errors of the
drawing rather than of the finding.

    pipeline segmenter predict --model RUN VAL_IMAGES --out PRED     # label PNGs named as the dataset's
    python3 scripts/segmenter_blob_recall.py DATASET/labels PRED/labels [--class 3] [--small 30] [--json FILE]

Only the label files that have a prediction of the same name are read. Installs numpy, scipy and Pillow with pip
when they are missing.
"""

import argparse
import json
import os
import subprocess
import sys

BINS = [0, 10, 30, 100, 300, 1000]


def ensure(module, package):
    try:
        __import__(module)
    except ImportError:
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", package], check=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("labels", help="folder of the true label PNGs (class ids)")
    parser.add_argument("predictions", help="folder of the predicted label PNGs, named as the labels")
    parser.add_argument("--class", dest="cls", type=int, default=3, help="class id (default 3, human)")
    parser.add_argument("--small", type=int, default=30, help="blobs under this many pixels count as small")
    parser.add_argument("--json", help="also write the figures to this file")
    args = parser.parse_args()
    for module, package in [("numpy", "numpy"), ("scipy", "scipy"), ("PIL", "Pillow")]:
        ensure(module, package)
    import numpy as np
    from PIL import Image
    from scipy import ndimage

    names = sorted(n for n in os.listdir(args.predictions) if n.endswith(".png"))
    if not names:
        sys.exit(f"{args.predictions}: no PNG predictions")
    edges = BINS + [float("inf")]
    blobs = [0] * len(BINS)
    pixels = [0] * len(BINS)
    found = [0] * len(BINS)
    false = 0
    missed_on_edge, false_on_edge = 0, 0
    square = np.ones((3, 3), bool)  # 8-connected neighbourhood of the outline
    small_found, small_pixels = 0, 0
    for name in names:
        path = os.path.join(args.labels, name)
        if not os.path.isfile(path):
            sys.exit(f"{path}: no label for prediction {name}")
        truth = np.array(Image.open(path))
        pred = np.array(Image.open(os.path.join(args.predictions, name)))
        if truth.shape != pred.shape:
            sys.exit(f"{name}: label {truth.shape} and prediction {pred.shape} differ in size")
        mask = truth == args.cls
        hit = pred == args.cls
        false += int((hit & ~mask).sum())
        ring = ndimage.binary_dilation(mask, square) & ~ndimage.binary_erosion(mask, square)
        missed_on_edge += int((mask & ~hit & ring).sum())
        false_on_edge += int((hit & ~mask & ring).sum())
        lab, n = ndimage.label(mask)
        if n == 0:
            continue
        index = range(1, n + 1)
        for size, got in zip(ndimage.sum(mask, lab, index), ndimage.sum(hit, lab, index)):
            b = max(i for i, lo in enumerate(BINS) if size >= lo)
            blobs[b] += 1
            pixels[b] += int(size)
            found[b] += int(got)
            if size < args.small:
                small_pixels += int(size)
                small_found += int(got)
    total, hits = sum(pixels), sum(found)
    iou = hits / (total + false) if total + false else float("nan")
    whole = (small_found + total - small_pixels) / (total + false) if total + false else float("nan")
    rows = []
    print(f"{len(names)} images, class {args.cls}")
    print("| blob size (pixels) | blobs | pixels | found | recall |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for b in range(len(BINS)):
        hi = edges[b + 1]
        span = f"{BINS[b]}-{hi - 1}" if hi != float("inf") else f"{BINS[b]} or more"
        recall = found[b] / pixels[b] if pixels[b] else float("nan")
        rows.append({"size": span, "blobs": blobs[b], "pixels": pixels[b], "found": found[b], "recall": recall})
        print(f"| {span} | {blobs[b]:,} | {pixels[b]:,} | {found[b]:,} | {recall:.3f} |")
    print(f"class pixels {total:,}, found {hits:,}, predicted elsewhere {false:,}: IoU {iou:.3f}")
    print(f"IoU if every blob of at least {args.small} pixels were found whole: {whole:.3f}")
    missed = total - hits
    print(f"on the outline (within 1 pixel of a label edge): {missed_on_edge:,} of the {missed:,} missed pixels, "
          f"{false_on_edge:,} of the {false:,} false ones")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"images": len(names), "class": args.cls, "bins": rows, "false": false, "iou": iou,
                       "iou_if_large_found": whole, "small": args.small,
                       "missed_on_edge": missed_on_edge, "false_on_edge": false_on_edge}, f, indent=1)
            f.write("\n")


if __name__ == "__main__":
    main()
