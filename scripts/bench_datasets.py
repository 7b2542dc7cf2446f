#!/usr/bin/env python3
"""Speed of the segmentation-data stage, ours and the peer (albumentations) in one run.

1. Generation: `pipeline dataset generate --count N --size 256x256` on the bundled campus
   (imported once beforehand, untimed), whole process wall time including rendering, PNG
   encoding and writing every file; RAYON_NUM_THREADS = each thread count; median of RUNS.
2. Augmentation, the thesis's chain (random crop to 80 % of each side, rotation within
   +-10 degrees, horizontal flip p 0.5, Gaussian blur sigma 0.5-1.5 p 0.5, Gaussian noise
   sigma 5-15 p 0.5) on the same CamVid 480x360 train images and labels, decoded once
   beforehand (untimed), in memory, the same number of threads:
   - ours: `datasets/examples/bench_augment.rs` (release), a rayon pool of T threads;
   - albumentations (installed from PyPI when missing): the same five transforms in an
     A.Compose with the mask, T worker processes each holding the images (spawned; one
     OpenCV thread each), and also one process with cv2.setNumThreads(T).
   One untimed warm-up run each, then RUNS timed runs; images per second, median.

Usage (from the repository root, with ../shared/data beside it):
    cargo build --release -p pipeline --example bench_augment -p datasets
    python3 scripts/bench_datasets.py [--runs 5] [--threads 1,2] [--images 100]
        [--gen-count 2000] [--out docs/benchmarks/datasets.json] [--skip-generation]
    (--skip-generation needs no pipeline binary and keeps the generation figures of the
    existing --out file, with their date.)
"""
import argparse
import json
import multiprocessing
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def ensure_albumentations():
    try:
        import albumentations  # noqa: F401
    except ImportError:
        subprocess.check_call([sys.executable, "-m", "pip", "install", "--quiet", "albumentations"])


def target_dir():
    return Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))


# ---------------------------------------------------------------- generation

def bench_generation(pipeline, count, runs, threads):
    work = Path(tempfile.mkdtemp(prefix="bench_datasets_"))
    try:
        subprocess.check_call(
            [str(pipeline), "-q", "--rerun", "off", "map", "import",
             str(ROOT / "data/osm/northwestern_nu.osm.pbf"), "--out", str(work / "map")])
        rates = []
        for run in range(runs + 1):
            out = work / f"gen{run}"
            env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
            start = time.perf_counter()
            subprocess.check_call(
                [str(pipeline), "-q", "--rerun", "off", "--seed", str(run), "dataset", "generate",
                 "--map", str(work / "map"), "--count", str(count), "--size", "256x256",
                 "--out", str(out)], env=env)
            seconds = time.perf_counter() - start
            written = len(list((out / "labels").iterdir()))
            if written != count:
                raise SystemExit(f"generation wrote {written} labels, not {count}")
            shutil.rmtree(out)
            if run > 0:  # the first run warms the page cache
                rates.append(count / seconds)
        return {"threads": threads, "count": count, "runs_images_per_second": rates,
                "median_images_per_second": statistics.median(rates)}
    finally:
        shutil.rmtree(work, ignore_errors=True)


# ---------------------------------------------------------------- albumentations

IMAGES = []
LABELS = []
CHAIN = None


def thesis_chain(height, width):
    import albumentations as A
    import cv2
    crop_h, crop_w = round(height * 0.8), round(width * 0.8)
    return A.Compose([
        A.RandomCrop(height=crop_h, width=crop_w, p=1.0),
        A.Rotate(limit=10, p=1.0, border_mode=cv2.BORDER_CONSTANT, fill=0, fill_mask=255),
        A.HorizontalFlip(p=0.5),
        A.GaussianBlur(blur_limit=0, sigma_limit=(0.5, 1.5), p=0.5),
        # std_range is a fraction of the maximum value (255 for uint8): sigma 5-15.
        A.GaussNoise(std_range=(5 / 255, 15 / 255), p=0.5),
    ])


def load_camvid(camvid, count):
    import cv2
    global CHAIN
    for line in (camvid / "train.txt").read_text().splitlines()[:count]:
        image, label = line.split()
        IMAGES.append(cv2.cvtColor(cv2.imread(str(camvid / image)), cv2.COLOR_BGR2RGB))
        LABELS.append(cv2.imread(str(camvid / label), cv2.IMREAD_GRAYSCALE))
    CHAIN = thesis_chain(*IMAGES[0].shape[:2])


def augment_indices(indices):
    done = 0
    for i in indices:
        out = CHAIN(image=IMAGES[i], mask=LABELS[i])
        done += out["image"].size > 0
    return done


def worker_init(camvid, count):
    import cv2
    cv2.setNumThreads(1)
    load_camvid(camvid, count)


def bench_albumentations(camvid, count, runs, threads):
    import cv2
    n = len(IMAGES)
    results = {}
    # T worker processes, each loading the images itself (untimed), one OpenCV thread each.
    # Spawned, not forked: forking after OpenCV has started its threads can deadlock.
    ctx = multiprocessing.get_context("spawn")
    with ctx.Pool(threads, initializer=worker_init, initargs=(camvid, count)) as pool:
        chunks = [list(range(k, n, threads)) for k in range(threads)]
        rates = []
        for run in range(runs + 1):
            start = time.perf_counter()
            done = sum(pool.map(augment_indices, chunks))
            seconds = time.perf_counter() - start
            assert done == n
            if run > 0:
                rates.append(n / seconds)
        results["processes"] = {"threads": threads, "runs_images_per_second": rates,
                                "median_images_per_second": statistics.median(rates)}
    # One process, OpenCV's own threads.
    cv2.setNumThreads(threads)
    rates = []
    for run in range(runs + 1):
        start = time.perf_counter()
        assert augment_indices(range(n)) == n
        seconds = time.perf_counter() - start
        if run > 0:
            rates.append(n / seconds)
    results["opencv_threads"] = {"threads": threads, "runs_images_per_second": rates,
                                 "median_images_per_second": statistics.median(rates)}
    return results


def bench_ours(example, camvid, count, runs, threads):
    out = subprocess.check_output(
        [str(example), "--camvid", str(camvid), "--images", str(count), "--runs", str(runs),
         "--threads", str(threads)])
    return json.loads(out)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--threads", default="1,2")
    parser.add_argument("--images", type=int, default=100, help="CamVid train images to augment")
    parser.add_argument("--gen-count", type=int, default=2000)
    parser.add_argument("--gen-runs", type=int, default=3)
    parser.add_argument("--camvid", type=Path, default=ROOT.parent / "shared/data/segmentation/camvid")
    parser.add_argument("--pipeline", type=Path, default=target_dir() / "release/pipeline")
    parser.add_argument("--example", type=Path, default=target_dir() / "release/examples/bench_augment")
    parser.add_argument("--out", type=Path, default=ROOT / "docs/benchmarks/datasets.json")
    parser.add_argument("--skip-generation", action="store_true")
    args = parser.parse_args()
    threads = [int(t) for t in args.threads.split(",")]
    needed = (args.example,) if args.skip_generation else (args.pipeline, args.example)
    for path in needed:
        if not path.exists():
            raise SystemExit(f"{path} is missing: cargo build --release -p pipeline -p datasets --example bench_augment")
    if not (args.camvid / "train.txt").exists():
        raise SystemExit(f"{args.camvid}/train.txt is missing: CamVid from ../shared/data is needed")

    ensure_albumentations()
    import albumentations
    import cv2
    load_camvid(args.camvid, args.images)

    report = {
        "date": time.strftime("%Y-%m-%d"),
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "albumentations": albumentations.__version__, "opencv": cv2.__version__,
        "generation": [], "augmentation": [],
    }
    if args.skip_generation and args.out.exists():
        # Keep the last generation figures, with the date they were measured.
        previous = json.loads(args.out.read_text())
        report["generation"] = previous.get("generation", [])
        report["generation_date"] = previous.get("generation_date", previous.get("date"))
    for t in [] if args.skip_generation else threads:
        gen = bench_generation(args.pipeline, args.gen_count, args.gen_runs, t)
        report["generation"].append(gen)
        print(f"generate 256x256, {t} thread(s): {gen['median_images_per_second']:.1f} images/s", flush=True)
    for t in threads:
        ours = bench_ours(args.example, args.camvid, args.images, args.runs, t)
        peer = bench_albumentations(args.camvid, args.images, args.runs, t)
        best_peer = max(p["median_images_per_second"] for p in peer.values())
        row = {"threads": t, "ours": ours, "albumentations": peer,
               "ratio_to_best_albumentations": ours["median_images_per_second"] / best_peer}
        report["augmentation"].append(row)
        print(f"thesis chain, {t} thread(s): ours {ours['median_images_per_second']:.1f} images/s, "
              f"albumentations {peer['processes']['median_images_per_second']:.1f} (processes) / "
              f"{peer['opencv_threads']['median_images_per_second']:.1f} (OpenCV threads): "
              f"{row['ratio_to_best_albumentations']:.2f}x the best", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
