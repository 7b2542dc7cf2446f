#!/usr/bin/env python3
"""How far the traffic world drives from real drivers: INTERACTION FT and EP.

Converts the recordings (`pipeline logs convert`), calibrates on FT 000-007, compares the
world with FT 008-009 (never used in the fit) calibrated and uncalibrated, with FT's
calibration on EP 000-001 (another roundabout), and leaves each FT recording out in turn
(calibrated on the other nine, compared with it). Prints the tables of docs/agents.md.

    python3 scripts/traffic_realism.py [--pipeline target/release/pipeline] [--data ../shared/data]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

METRICS = ["circulating_speed", "yield_line_speed", "accepted_gap", "rejected_gap",
           "follow_up_headway", "yield_line_delay", "entry_flow", "stopped"]


def run(cmd):
    out = subprocess.run(cmd, capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"failed: {' '.join(cmd)}\n{out.stderr}")
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--pipeline", default="target/release/pipeline")
    ap.add_argument("--data", default="../shared/data")
    args = ap.parse_args()
    base = os.path.join(args.data, "trajectories/interaction")
    pipeline = [os.path.abspath(args.pipeline), "--rerun", "off", "-q"]
    maps = {s: os.path.join(base, f"maps/DR_USA_Roundabout_{s}.osm") for s in ("FT", "EP")}
    tmp = tempfile.mkdtemp(prefix="realism_")
    logs = {}
    for scenario, count in (("FT", 10), ("EP", 2)):
        for n in range(count):
            tracks = os.path.join(base, f"recorded_trackfiles/DR_USA_Roundabout_{scenario}/vehicle_tracks_{n:03}.csv.gz")
            out = os.path.join(tmp, f"{scenario.lower()}_{n:03}.mcap")
            run(pipeline + ["logs", "convert", tracks, "--map", maps[scenario], "--out", out])
            logs[(scenario, n)] = out

    def calibrate(ns, name):
        out = os.path.join(tmp, f"{name}.toml")
        cmd = pipeline + ["sim", "calibrate", "--map", maps["FT"], "--out", out]
        for n in ns:
            cmd += ["--log", logs[("FT", n)]]
        start = time.monotonic()
        run(cmd)
        return out, time.monotonic() - start

    def realism(scenario, ns, config, name):
        out = os.path.join(tmp, name)
        cmd = list(pipeline)
        if config:
            cmd += ["--config", config]
        cmd += ["sim", "realism", "--map", maps[scenario], "--out", out]
        for n in ns:
            cmd += ["--log", logs[(scenario, n)]]
        run(cmd)
        with open(os.path.join(out, "realism.json")) as f:
            return json.load(f)

    calib, seconds = calibrate(range(8), "ft_000_007")
    print(f"calibration on FT 000-007: {seconds:.1f} s ({calib})")
    with open(calib) as f:
        print(f.read())
    held = realism("FT", [8, 9], calib, "ft_heldout")
    uncal = realism("FT", [8, 9], None, "ft_heldout_uncalibrated")
    ep = realism("EP", [0, 1], calib, "ep")
    ep_uncal = realism("EP", [0, 1], None, "ep_uncalibrated")
    print("| metric | FT 008-009 calibrated KS (W) | uncalibrated KS (W) | EP with FT's calibration KS (W) | EP uncalibrated KS (W) |")
    print("| --- | --- | --- | --- | --- |")
    for m in METRICS:
        cells = [f"{r['metrics'][m]['ks']:.3f} ({r['metrics'][m]['wasserstein']:.2f})" for r in (held, uncal, ep, ep_uncal)]
        print(f"| {m} | " + " | ".join(cells) + " |")
    print()
    print("| metric | real FT 008-009 mean, p10 / p50 / p90 | calibrated world | real EP | world on EP |")
    print("| --- | --- | --- | --- | --- |")
    for m in METRICS:
        def s(x):
            return f"{x['mean']:.2f}, {x['p10']:.2f} / {x['p50']:.2f} / {x['p90']:.2f}"
        print(f"| {m} | {s(held['metrics'][m]['real'])} | {s(held['metrics'][m]['sim'])} | "
              f"{s(ep['metrics'][m]['real'])} | {s(ep['metrics'][m]['sim'])} |")
    print()
    loo = {m: [] for m in METRICS}
    times = []
    for k in range(10):
        c, seconds = calibrate([n for n in range(10) if n != k], f"loo_{k}")
        times.append(seconds)
        r = realism("FT", [k], c, f"loo_{k}")
        for m in METRICS:
            loo[m].append(r["metrics"][m]["ks"])
    print(f"leave-one-out over FT (calibrated on nine, {min(times):.1f}-{max(times):.1f} s each):")
    print("| metric | mean KS | worst KS | recording of the worst |")
    print("| --- | --- | --- | --- |")
    for m in METRICS:
        ks = loo[m]
        worst = max(range(10), key=lambda k: ks[k])
        print(f"| {m} | {sum(ks) / len(ks):.3f} | {ks[worst]:.3f} | {worst:03} |")


if __name__ == "__main__":
    main()
