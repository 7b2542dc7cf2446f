#!/usr/bin/env python3
"""Speed of the log reader: ours and the Python readers in one run.

The Husky drive (16,806 messages: IMU, wheel odometry, GPS) in its three storages under
../shared/data/logs/husky: plain MCAP (lz4 chunks), rosbag2 with MCAP storage (zstd chunks) and
rosbag2 with sqlite3 storage. Two modes, compared like for like:

- raw: every message read in storage order, its payload not decoded (ours: chunks decompressed,
  CRCs checked, records parsed, payload lengths summed; Python: the same iteration, payload
  lengths summed);
- decoded: every message also decoded from CDR into a message object (ours: typed structs
  kept in one vector, `read_decoded`; mcap: `iter_decoded_messages` with mcap-ros2-support's
  decoder; rosbags: `AnyReader.deserialize`, its types registered from the bag's definitions).

Readers per storage: plain MCAP - ours, mcap; rosbag2 MCAP - ours, rosbags, and mcap on the
bag's .mcap file; rosbag2 sqlite3 - ours, rosbags. Every side is timed inside its own process,
opening the log included, process start-up excluded; one untimed warm-up pass per mode and
reader (the files are then in the page cache for everybody), then RUNS timed passes, median.
The ratio is our messages/s over the fastest Python reader's on the same storage and mode.

Usage (from the repository root, with ../shared/data beside it):
    cargo build --release -p logs --example bench_logs
    pip install mcap mcap-ros2-support rosbags
    python3 scripts/bench_logs.py [--runs 7] [--out docs/benchmarks/logs.json]
"""
import argparse
import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
HUSKY = ROOT.parent / "shared/data/logs/husky"
STORAGES = {
    "mcap": HUSKY / "husky.mcap",
    "bag_mcap": HUSKY / "husky_mcap",
    "bag_sqlite3": HUSKY / "husky_db3",
}
MESSAGES = 16806


def target_dir():
    return Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))


def versions():
    from importlib.metadata import version

    return {p: version(p) for p in ("mcap", "mcap-ros2-support", "rosbags")}


# ------------------------------------------------------------------ Python readers

def mcap_raw(path):
    from mcap.reader import make_reader

    n = size = 0
    with open(path, "rb") as f:
        # File order, as ours and rosbags read.
        for _schema, _channel, message in make_reader(f).iter_messages(log_time_order=False):
            n += 1
            size += len(message.data)
    return n, size


def mcap_decoded(path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out = []
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _s, _c, _m, decoded in reader.iter_decoded_messages(log_time_order=False):
            out.append(decoded)
    return len(out), 0


def rosbags_raw(path):
    from rosbags.highlevel import AnyReader

    n = size = 0
    with AnyReader([Path(path)]) as reader:
        for _connection, _timestamp, raw in reader.messages():
            n += 1
            size += len(raw)
    return n, size


def rosbags_decoded(path):
    from rosbags.highlevel import AnyReader

    out = []
    with AnyReader([Path(path)]) as reader:
        for connection, _timestamp, raw in reader.messages():
            out.append(reader.deserialize(raw, connection.msgtype))
    return len(out), 0


def time_python(fn, path, runs):
    expected = fn(path)  # warm-up
    seconds = []
    for _ in range(runs):
        t = time.perf_counter()
        got = fn(path)
        seconds.append(time.perf_counter() - t)
        assert got == expected, (got, expected)
    median = statistics.median(seconds)
    return {
        "messages": expected[0],
        "seconds": seconds,
        "median_s": median,
        "messages_per_s": expected[0] / median,
    }


# ------------------------------------------------------------------ ours

def ours(runs):
    exe = target_dir() / "release/examples/bench_logs"
    if not exe.exists():
        sys.exit(f"{exe} is missing: cargo build --release -p logs --example bench_logs")
    out = subprocess.run(
        [str(exe), "--runs", str(runs)] + [str(p) for p in STORAGES.values()],
        check=True, capture_output=True, text=True).stdout
    results = {}
    for line, storage in zip(out.splitlines(), STORAGES):
        results[storage] = json.loads(line)
    return results


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--out", type=Path, default=ROOT / "docs/benchmarks/logs.json")
    args = ap.parse_args()

    rust = ours(args.runs)
    inner_mcap = STORAGES["bag_mcap"] / "husky_mcap.mcap"
    peers = {
        "mcap": [("mcap", mcap_raw, mcap_decoded, STORAGES["mcap"])],
        "bag_mcap": [
            ("rosbags", rosbags_raw, rosbags_decoded, STORAGES["bag_mcap"]),
            ("mcap (on the bag's .mcap file)", mcap_raw, mcap_decoded, inner_mcap),
        ],
        "bag_sqlite3": [("rosbags", rosbags_raw, rosbags_decoded, STORAGES["bag_sqlite3"])],
    }
    rows = []
    for storage, path in STORAGES.items():
        for mode in ("raw", "decoded"):
            ours_rate = rust[storage][mode]["messages_per_s"]
            assert rust[storage][mode]["messages"] == MESSAGES, rust[storage][mode]
            row = {
                "storage": storage,
                "path": str(path.relative_to(ROOT.parent)),
                "mode": mode,
                "ours": rust[storage][mode],
                "peers": {},
            }
            for name, raw_fn, dec_fn, peer_path in peers[storage]:
                fn = raw_fn if mode == "raw" else dec_fn
                result = time_python(fn, peer_path, args.runs)
                assert result["messages"] == MESSAGES, (name, result)
                row["peers"][name] = result
            best_name, best = max(row["peers"].items(), key=lambda kv: kv[1]["messages_per_s"])
            row["fastest_peer"] = best_name
            row["ratio_vs_fastest_peer"] = ours_rate / best["messages_per_s"]
            rows.append(row)
            print(f"{storage:12} {mode:8} ours {ours_rate:12,.0f} msg/s  "
                  + "  ".join(f"{n} {r['messages_per_s']:10,.0f} msg/s" for n, r in row["peers"].items())
                  + f"  ratio {row['ratio_vs_fastest_peer']:.1f}x", flush=True)

    report = {
        "date": datetime.date.today().isoformat(),
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "python": platform.python_version(),
        "packages": versions(),
        "runs": args.runs,
        "command": "python3 scripts/bench_logs.py --runs %d" % args.runs,
        "results": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
