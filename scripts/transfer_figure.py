#!/usr/bin/env python3
"""Generated samples beside real camera frames, with a segmenter's predictions on both.

Each row is one picture: the image, the model's labels over it (`segmenter predict`'s
overlay) and, when the dataset has labels, its ground truth in the same colours.

    python3 scripts/transfer_figure.py --generated runs/gen_urban --real runs/transfer/camvid \\
        --split test --count 4 --out runs/transfer_figure.png

Without `--model` the shipped model labels the images. `--real` is optional: the figure in
docs/images/ holds only generated images, since CamVid's pixels may not be copied into the
repository; the command above makes the full figure locally.
"""

import argparse
import json
import subprocess
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

ROOT = Path(__file__).resolve().parent.parent
# The class colours of `segmenter predict`'s overlays (datasets::classes).
COLOURS = {0: (128, 64, 128), 1: (255, 220, 0), 2: (0, 0, 142), 3: (220, 20, 60), 4: (110, 110, 110)}


def items(dataset, split, count):
    rows = [json.loads(l) for l in (dataset / "manifest.jsonl").read_text().splitlines() if l.strip()]
    rows = [r for r in rows if split == "all" or r.get("split") == split]
    step = max(1, len(rows) // count)
    return rows[::step][:count]


def colour_label(label):
    out = np.zeros(label.shape + (3,), np.uint8)
    for k, c in COLOURS.items():
        out[label == k] = c
    return out


def predict(pipeline, model, dataset, chosen, work):
    folder = work / dataset.name
    folder.mkdir(parents=True)
    for item in chosen:
        (folder / Path(item["image"]).name).symlink_to((dataset / item["image"]).resolve())
    out = work / f"{dataset.name}_out"
    cmd = [str(pipeline), "--rerun", "off", "segmenter", "predict", str(folder), "--out", str(out)]
    if model:
        cmd += ["--model", str(model)]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return out


def rows(dataset, chosen, out, width):
    result = []
    for item in chosen:
        stem = Path(item["image"]).stem
        image = Image.open(dataset / item["image"]).convert("RGB")
        h = round(image.height * width / image.width)
        tiles = [image, Image.open(out / "overlays" / f"{stem}.png").convert("RGB")]
        truth = np.array(Image.open(dataset / item["label"]))
        tiles.append(Image.fromarray(colour_label(truth)))
        result.append([t.resize((width, h), Image.NEAREST if k == 2 else Image.BILINEAR)
                       for k, t in enumerate(tiles)])
    return result


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--generated", type=Path, required=True)
    parser.add_argument("--real", type=Path, help="an imported real dataset (e.g. CamVid)")
    parser.add_argument("--split", default="test", help="the real dataset's split")
    parser.add_argument("--generated-split", default="val")
    parser.add_argument("--count", type=int, default=4)
    parser.add_argument("--model", type=Path)
    parser.add_argument("--pipeline", type=Path, default=ROOT / "target/release/pipeline")
    parser.add_argument("--width", type=int, default=256)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        sets = [(args.generated, args.generated_split)] + ([(args.real, args.split)] if args.real else [])
        columns = []
        for dataset, split in sets:
            chosen = items(dataset, split, args.count)
            if not chosen:
                raise SystemExit(f"{dataset}: no items in the {split} split")
            out = predict(args.pipeline, args.model, dataset, chosen, tmp)
            columns.append((dataset.name, rows(dataset, chosen, out, args.width)))
    gap, head = 6, 22
    col_w = 3 * args.width + 2 * gap
    height = head + max(sum(r[0].height + gap for r in col) for _, col in columns)
    figure = Image.new("RGB", (len(columns) * col_w + (len(columns) - 1) * 3 * gap, height), "white")
    draw = ImageDraw.Draw(figure)
    for c, (name, col) in enumerate(columns):
        x0 = c * (col_w + 3 * gap)
        for k, title in enumerate(["image", "prediction", "ground truth"]):
            draw.text((x0 + k * (args.width + gap) + 4, 5), f"{name}: {title}", fill="black")
        y = head
        for row in col:
            for k, tile in enumerate(row):
                figure.paste(tile, (x0 + k * (args.width + gap), y))
            y += row[0].height + gap
    args.out.parent.mkdir(parents=True, exist_ok=True)
    figure.save(args.out, optimize=True)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
