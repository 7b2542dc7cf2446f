#!/usr/bin/env python3
"""A page of dataset samples for the docs: per row the image, its label in the class colours
of the dataset's card, and the label laid over the image (50 %).

Usage: python3 scripts/dataset_samples.py DATASET OUT.jpg [--count 6] [--every 333]
Takes items 0, every, 2*every, ... of the manifest (sorted by id). Needs numpy and OpenCV
(`pip install opencv-python-headless`).
"""
import argparse
import json
from pathlib import Path

import cv2
import numpy as np


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--count", type=int, default=6)
    parser.add_argument("--every", type=int, default=333)
    args = parser.parse_args()

    card = json.loads((args.dataset / "card.json").read_text())
    palette = np.zeros((256, 3), np.uint8)
    palette[:] = (255, 0, 255)  # a value outside the class table shows magenta
    for c in card["classes"]:
        palette[c["id"]] = c["color"]
    items = [json.loads(line) for line in (args.dataset / "manifest.jsonl").read_text().splitlines() if line]
    rows = []
    for k in range(args.count):
        item = items[(k * args.every) % len(items)]
        image = cv2.cvtColor(cv2.imread(str(args.dataset / item["image"])), cv2.COLOR_BGR2RGB)
        label = cv2.imread(str(args.dataset / item["label"]), cv2.IMREAD_UNCHANGED)
        coloured = palette[label]
        overlay = (image.astype(np.uint16) + coloured) // 2
        gap = np.full((image.shape[0], 4, 3), 255, np.uint8)
        rows.append(np.hstack([image, gap, coloured, gap, overlay.astype(np.uint8)]))
        rows.append(np.full((4, rows[-1].shape[1], 3), 255, np.uint8))
    page = np.vstack(rows[:-1])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), cv2.cvtColor(page, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(f"wrote {args.out} ({page.shape[1]}x{page.shape[0]})")


if __name__ == "__main__":
    main()
