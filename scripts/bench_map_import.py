#!/usr/bin/env python3
"""Times `pipeline map import` against SUMO netconvert 1.15 on the same files, in one run.

For each file: one untimed warm-up of each tool, then RUNS timed runs of each, alternating
(ours, netconvert, ours, ...) so both see the same machine state; the figure is the median
wall time of the whole process (time.perf_counter around subprocess.run). Ours writes its
complete output folder (native JSON and binary, GeoJSON, PNG preview, rerun recording,
summary.json). netconvert runs with the reference options of
../shared/data/osm/reference/README.md and, as there, reads XML only: a PBF is converted
with `osmium cat` once beforehand, outside the timing, as is a gzipped XML file.

Usage (from the repository root, after `cargo build --release -p pipeline`):
    SUMO_HOME=/usr/share/sumo python3 scripts/bench_map_import.py [--runs 7] [--out docs/benchmarks/map_import.json]
        [--pipeline PATH] [--compare PATH]
The binary is $CARGO_TARGET_DIR/release/pipeline when CARGO_TARGET_DIR is set, else
target/release/pipeline; --pipeline names another. --compare PATH times a second build of
ours (an earlier one, say) in the same alternation (ours, netconvert, compared, ours, ...), so
a before/after comparison sees the same machine state even when other work comes and goes.
Needs: netconvert (Debian `sumo`), osmium (Debian `osmium-tool`).
"""
import argparse
import json
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
DATA = ROOT.parent / "shared" / "data" / "osm"
TARGET_DIR = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
PIPELINE = TARGET_DIR / "release" / "pipeline"
CASES = [
    # (label, our input, netconvert's XML input or None to convert the PBF)
    ("northwestern_nu (XML)", "northwestern_nu.osm", "northwestern_nu.osm"),
    ("northwestern_nu (PBF)", "northwestern_nu.osm.pbf", "northwestern_nu.osm"),
    ("leeds_cycleway (XML)", "leeds_cycleway.osm", "leeds_cycleway.osm"),
    ("helsinki (PBF)", "helsinki.osm.pbf", None),
    ("andorra (PBF)", "roundabouts/andorra.osm.pbf", None),
    ("campo-grande (XML.gz)", "roundabouts/campo-grande.osm.gz", None),
    ("krems (XML.gz)", "roundabouts/krems.osm.gz", None),
]
NETCONVERT_OPTS = ["--keep-edges.by-vclass", "passenger", "--roundabouts.guess", "--junctions.join", "--output.street-names"]


def timed(cmd, env=None):
    t = time.perf_counter()
    r = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    dt = time.perf_counter() - t
    if r.returncode != 0:
        sys.exit(f"failed ({r.returncode}): {' '.join(map(str, cmd))}\n{r.stderr.decode(errors='replace')}")
    return dt


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks" / "map_import.json"))
    ap.add_argument("--pipeline", type=Path, default=PIPELINE, help=f"the binary to time (default {PIPELINE})")
    ap.add_argument("--compare", type=Path, help="another pipeline binary to time in the same alternation")
    args = ap.parse_args()
    pipeline = args.pipeline
    if args.runs < 5:
        sys.exit("--runs must be at least 5 (the figure is a median)")
    for tool in ("netconvert", "osmium"):
        if not shutil.which(tool):
            sys.exit(f"{tool} not found: apt-get install sumo osmium-tool")
    if not pipeline.exists():
        sys.exit(f"{pipeline} not found: cargo build --release -p pipeline")
    if args.compare and not args.compare.exists():
        sys.exit(f"{args.compare} not found")
    env = dict(os.environ, SUMO_HOME=os.environ.get("SUMO_HOME", "/usr/share/sumo"))
    version = subprocess.run(["netconvert", "--version"], capture_output=True, text=True, env=env).stdout.splitlines()[0]
    results = []
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for label, ours_in, their_in in CASES:
            ours_path = DATA / ours_in
            if their_in is None:
                their_path = tmp / (Path(ours_in).name.split(".")[0] + ".osm")
                subprocess.run(["osmium", "cat", str(ours_path), "-f", "osm", "-o", str(their_path), "--overwrite"], check=True)
            else:
                their_path = DATA / their_in
            n = [0]

            def ours(binary=pipeline):
                n[0] += 1
                out = tmp / f"ours{n[0]}"
                dt = timed([str(binary), "-q", "map", "import", str(ours_path), "--out", str(out)])
                shutil.rmtree(out)
                return dt

            def theirs():
                return timed(["netconvert", "--osm-files", str(their_path), *NETCONVERT_OPTS, "-o", str(tmp / "net.xml")], env)

            ours(), theirs()  # warm-up: file cache, dynamic loader
            if args.compare:
                ours(args.compare)
            ours_t, their_t, compare_t = [], [], []
            for _ in range(args.runs):
                ours_t.append(ours())
                their_t.append(theirs())
                if args.compare:
                    compare_t.append(ours(args.compare))
            row = {
                "case": label,
                "ours_input": ours_in,
                "netconvert_input": their_in or f"{ours_in} converted to XML with osmium (not timed)",
                "ours_median_s": round(statistics.median(ours_t), 4),
                "netconvert_median_s": round(statistics.median(their_t), 4),
                "ours_runs_s": [round(x, 4) for x in ours_t],
                "netconvert_runs_s": [round(x, 4) for x in their_t],
            }
            row["speedup"] = round(row["netconvert_median_s"] / row["ours_median_s"], 1)
            line = f"{label:24s} ours {row['ours_median_s']*1e3:7.1f} ms  netconvert {row['netconvert_median_s']*1e3:7.1f} ms  ratio {row['speedup']:5.1f}x"
            if args.compare:
                row["compared_median_s"] = round(statistics.median(compare_t), 4)
                row["compared_runs_s"] = [round(x, 4) for x in compare_t]
                row["compared_speedup"] = round(row["netconvert_median_s"] / row["compared_median_s"], 1)
                line += f"  | compared {row['compared_median_s']*1e3:7.1f} ms  ratio {row['compared_speedup']:5.1f}x"
            results.append(row)
            print(line, flush=True)
    out = {
        "what": "median wall time of `pipeline -q map import F --out DIR` (all outputs) vs `netconvert --osm-files F.osm " + " ".join(NETCONVERT_OPTS) + " -o net.xml`",
        "runs": args.runs,
        "pipeline": str(pipeline),
        "compared": str(args.compare) if args.compare else None,
        "netconvert": version,
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
        # Other work on the machine slows both tools; the 1, 5 and 15 minute load averages.
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
        "date": time.strftime("%Y-%m-%d"),
        "results": results,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
