#!/usr/bin/env python3
"""Do generated images help on real ones? The sequence-disjoint CamVid protocol.

CamVid's frames are grouped by sequence: 0016E5 trains, 0001TP validates (every choice is
made on it), 0006R0 is scored once. Three conditions, each trained for the same number of
optimiser steps (the same network and batch, so the same time) with several seeds:

  a  generated images only (validated on generated images): zero-shot transfer
  b  CamVid's training sequence only
  c  CamVid's training sequence plus generated images

Each model labels the frames with `segmenter predict`; this script scores the labels
against CamVid's (per image, then pooled), gives the mean and range over seeds, a 95 %
bootstrap interval over images (the seeds' mean IoU, images resampled together) and the
paired bootstrap of c minus b on the same images.

    python3 scripts/camvid_transfer.py --work runs/transfer --generated runs/gen_urban \\
        --seeds 1,2,3 --conditions a,b,c --split test

It uses the LibTorch build when `--device libtorch` (the default; docs/gpu.md), writes
`<work>/transfer.json` and prints a markdown table. Runs already finished are reused.
"""

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parent.parent
CLASSES = ["road", "lane_marking", "vehicle", "human", "other"]
SCORED = [0, 2, 3, 4]  # CamVid cannot label lane markings (they are road)
VAL_SEQUENCE, TEST_SEQUENCE = "0001TP", "0006R0"


def run(cmd, log=None):
    print("+", " ".join(str(c) for c in cmd), flush=True)
    if log is None:
        subprocess.run([str(c) for c in cmd], check=True)
        return
    with open(log, "w") as out:
        subprocess.run([str(c) for c in cmd], check=True, stdout=out, stderr=subprocess.STDOUT)


def pipeline_cmd(args):
    if args.device == "libtorch":
        return [ROOT / "target/libtorch/release/pipeline", "--device", "libtorch", "--rerun", "off"]
    return [ROOT / "target/release/pipeline", "--rerun", "off"]


def camvid_dataset(args, pipeline):
    """CamVid imported and split by sequence."""
    out = args.work / "camvid"
    if not (out / "split.json").exists():
        if not out.exists():
            run(pipeline + ["dataset", "import", "camvid", args.camvid, "--out", out])
        run(pipeline + ["dataset", "split", out, "--group-by", "prefix",
                        "--val-group", VAL_SEQUENCE, "--test-group", TEST_SEQUENCE])
    return out


def frames(camvid, split):
    """A folder of links to one split's images (what `segmenter predict` takes)."""
    folder = camvid.parent / f"camvid_{split}_images"
    items = [json.loads(l) for l in (camvid / "manifest.jsonl").read_text().splitlines() if l.strip()]
    items = [i for i in items if i.get("split") == split]
    folder.mkdir(exist_ok=True)
    for item in items:
        link = folder / Path(item["image"]).name
        if not link.exists():
            link.symlink_to((camvid / item["image"]).resolve())
    return folder, items


def train(args, pipeline, condition, seed, camvid):
    out = args.work / f"{condition}_s{seed}"
    if (out / "best" / "model.json").exists() and (out / "done").exists():
        return out
    data = {
        "a": ["--data", f"{args.generated}:1", "--val", args.generated],
        "b": ["--data", f"{camvid}:1", "--val", camvid],
        "c": ["--data", f"{camvid}:{args.camvid_weight}", "--data", f"{args.generated}:1", "--val", camvid],
    }[condition]
    if out.exists():
        run(["rm", "-rf", out])
    run(pipeline + ["--seed", seed, "segmenter", "train", "--settings", args.settings] + data
        + ["--out", out, "--epochs", args.epochs, "--samples-per-epoch", args.samples_per_epoch,
           "--val-limit", args.val_limit, "--threads", args.threads],
        log=args.work / f"{condition}_s{seed}.log")
    (out / "done").write_text("")
    return out


def predict(args, pipeline, model, images, name):
    out = args.work / "predictions" / f"{model.name}_{name}"
    if not (out / "labels").exists():
        run(pipeline + ["segmenter", "predict", "--model", model, images, "--out", out,
                        "--threads", args.threads], log=args.work / f"predict_{model.name}_{name}.log")
    return out / "labels"


def confusion(truth, pred):
    """Per-image confusion (truth rows, prediction columns) with CamVid's fold: a marking
    predicted on a road pixel is road."""
    pred = pred.copy()
    pred[(truth == 0) & (pred == 1)] = 0
    keep = truth != 255
    t, p = truth[keep].astype(np.int64), pred[keep].astype(np.int64)
    return np.bincount(t * 5 + p, minlength=25).reshape(5, 5)


def image_confusions(camvid, items, labels):
    out = []
    for item in items:
        truth = np.array(Image.open(camvid / item["label"]))
        pred = np.array(Image.open(labels / (Path(item["image"]).stem + ".png")))
        if pred.shape != truth.shape:
            raise SystemExit(f"{labels}: prediction of {item['id']} is {pred.shape}, label {truth.shape}")
        out.append(confusion(truth, pred))
    return np.stack(out)


def ious(conf):
    """IoU of the scored classes present in the truth (NaN when absent); conf [..., 5, 5]."""
    tp = np.diagonal(conf, axis1=-2, axis2=-1)
    truth = conf.sum(-1)
    pred = conf.sum(-2)
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = tp / (truth + pred - tp)
    iou = np.where(truth > 0, iou, np.nan)
    return iou[..., SCORED]


def miou(iou):
    return np.nanmean(iou, axis=-1)


def bootstrap(per_seed, resamples, rng):
    """per_seed: [seeds, images, 5, 5]. The seeds' mean IoU per class and mIoU, over image
    resamples: returns [resamples, len(SCORED) + 1]."""
    n = per_seed.shape[1]
    draws = rng.integers(0, n, size=(resamples, n))
    out = np.empty((resamples, len(SCORED) + 1))
    for r, idx in enumerate(draws):
        iou = ious(per_seed[:, idx].sum(1))  # [seeds, classes]
        out[r, :-1] = np.nanmean(iou, 0)
        out[r, -1] = np.nanmean(miou(iou))
    return out


def summary(per_seed, resamples, seed=0):
    iou = ious(per_seed.sum(1))  # [seeds, classes]
    m = miou(iou)
    boot = bootstrap(per_seed, resamples, np.random.default_rng(seed))
    lo, hi = np.nanpercentile(boot, [2.5, 97.5], axis=0)
    names = [CLASSES[c] for c in SCORED] + ["miou"]
    values = np.concatenate([iou, m[:, None]], 1)
    return {
        name: {
            "mean": float(np.nanmean(values[:, k])),
            "range": [float(np.nanmin(values[:, k])), float(np.nanmax(values[:, k]))],
            "ci95": [float(lo[k]), float(hi[k])],
            "per_seed": [float(v) for v in values[:, k]],
        }
        for k, name in enumerate(names)
    }


def paired(first, second, resamples, seed=1):
    """second minus first on the same images: difference of the seeds' mean figures."""
    n = first.shape[1]
    rng = np.random.default_rng(seed)
    names = [CLASSES[c] for c in SCORED] + ["miou"]

    def figures(per_seed, idx):
        iou = ious(per_seed[:, idx].sum(1))
        return np.concatenate([np.nanmean(iou, 0), [np.nanmean(miou(iou))]])

    point = figures(second, np.arange(n)) - figures(first, np.arange(n))
    diffs = np.array([figures(second, idx) - figures(first, idx)
                      for idx in rng.integers(0, n, size=(resamples, n))])
    lo, hi = np.nanpercentile(diffs, [2.5, 97.5], axis=0)
    # Two-sided bootstrap p-value: twice the share of resamples on the other side of 0.
    p = [float(min(1.0, 2 * min((diffs[:, k] <= 0).mean(), (diffs[:, k] >= 0).mean())))
         for k in range(len(names))]
    return {name: {"difference": float(point[k]), "ci95": [float(lo[k]), float(hi[k])], "p": p[k]}
            for k, name in enumerate(names)}


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--generated", type=Path, help="a generated dataset with train and val splits (a, c)")
    parser.add_argument("--camvid", type=Path, default=ROOT.parent / "shared/data/segmentation/camvid")
    parser.add_argument("--settings", type=Path, default=ROOT / "configs/segmenter_transfer.toml")
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("--conditions", default="a,b,c")
    parser.add_argument("--split", default="val", choices=["val", "test"],
                        help="score on the validation sequence (choices) or the test sequence (once)")
    parser.add_argument("--epochs", type=int, default=12)
    parser.add_argument("--samples-per-epoch", type=int, default=800)
    parser.add_argument("--camvid-weight", type=float, default=1.0, help="sampling weight of CamVid in c")
    parser.add_argument("--val-limit", type=int, default=62)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--device", default="libtorch", choices=["libtorch", "flex"])
    parser.add_argument("--resamples", type=int, default=1000)
    args = parser.parse_args()
    if not (args.camvid / "train.txt").exists():
        raise SystemExit(f"{args.camvid}/train.txt is missing: CamVid from ../shared/data is needed")
    conditions = args.conditions.split(",")
    if any(c in ("a", "c") for c in conditions) and not args.generated:
        raise SystemExit("conditions a and c need --generated DIR")
    args.work.mkdir(parents=True, exist_ok=True)
    pipeline = pipeline_cmd(args)
    camvid = camvid_dataset(args, pipeline)
    images, items = frames(camvid, args.split)
    seeds = [int(s) for s in args.seeds.split(",")]
    results = {"split": args.split, "sequence": {"val": VAL_SEQUENCE, "test": TEST_SEQUENCE}[args.split],
               "images": len(items), "seeds": seeds, "generated": str(args.generated),
               "steps": args.epochs * args.samples_per_epoch, "conditions": {}}
    confusions = {}
    for condition in conditions:
        per_seed = []
        for seed in seeds:
            model = train(args, pipeline, condition, seed, camvid)
            labels = predict(args, pipeline, model, images, args.split)
            per_seed.append(image_confusions(camvid, items, labels))
        confusions[condition] = np.stack(per_seed)
        results["conditions"][condition] = summary(confusions[condition], args.resamples)
    if "b" in confusions and "c" in confusions:
        results["c_minus_b"] = paired(confusions["b"], confusions["c"], args.resamples)
    (args.work / f"transfer_{args.split}.json").write_text(json.dumps(results, indent=2) + "\n")
    names = [CLASSES[c] for c in SCORED] + ["miou"]
    print(f"\n{args.split} ({results['sequence']}, {len(items)} frames), seeds {seeds}: mean (range) [95 % interval]")
    print("| condition | " + " | ".join(names) + " |")
    print("| --- |" + " ---: |" * len(names))
    for condition, s in results["conditions"].items():
        cells = [f"{s[n]['mean']:.3f} ({s[n]['range'][0]:.3f}-{s[n]['range'][1]:.3f}) "
                 f"[{s[n]['ci95'][0]:.3f}, {s[n]['ci95'][1]:.3f}]" for n in names]
        print(f"| {condition} | " + " | ".join(cells) + " |")
    if "c_minus_b" in results:
        d = results["c_minus_b"]
        print("| c − b | " + " | ".join(
            f"{d[n]['difference']:+.3f} [{d[n]['ci95'][0]:+.3f}, {d[n]['ci95'][1]:+.3f}] p {d[n]['p']:.3f}"
            for n in names) + " |")


if __name__ == "__main__":
    sys.exit(main())
