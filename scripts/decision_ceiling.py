#!/usr/bin/env python3
"""How far do simple observations explain the FT drivers' go / wait decisions?

The agents are judged by how many of the FT drivers' go and wait frames they agree with. This script
estimates what a strong classifier on hand-made features reaches, as a yardstick for the agents:
gradient-boosted trees (scikit-learn's HistGradientBoostingClassifier) trained on the go and wait frames
of FT 000-007 and scored on 008-009, then every recording held out in turn. The features come from
`cargo run --release -p logs --example decision_features` (its own speed now, 0.5 s, 1 s and 2 s
before, its slowest speed so far, the distance to the line, the time since the approach began, the
nearest circulating vehicle upstream of its entry with its arc distance, speed and time to arrive, the
vehicles within 40 m upstream, near the entry and on the ring, the vehicle ahead of it), with the labels
`replay eval` scores.

    python3 scripts/decision_ceiling.py --logs DIR [--features-bin PATH] [--out docs/benchmarks/decision_ceiling.json]

DIR holds ft_000.mcap ... ft_009.mcap (`pipeline logs convert`, docs/logs.md). Installs scikit-learn with
pip when it is missing.
"""

import argparse
import csv
import io
import json
import os
import subprocess
import sys

SHARED = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data")
MAP = os.path.join(SHARED, "trajectories", "interaction", "maps", "DR_USA_Roundabout_FT.osm")


def ensure_sklearn():
    try:
        import sklearn  # noqa: F401
    except ImportError:
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "scikit-learn"], check=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", required=True, help="folder with ft_000.mcap ... ft_009.mcap")
    ap.add_argument("--features-bin", help="the decision_features example (built when omitted)")
    ap.add_argument("--out", help="write the figures as JSON here")
    args = ap.parse_args()
    ensure_sklearn()
    import numpy as np
    from sklearn.ensemble import HistGradientBoostingClassifier

    binary = args.features_bin
    if binary is None:
        subprocess.run(["cargo", "build", "--release", "-p", "logs", "--example", "decision_features"],
                       check=True)
        target = os.environ.get("CARGO_TARGET_DIR", "target")
        binary = os.path.join(target, "release", "examples", "decision_features")
    names = [f"ft_{i:03d}" for i in range(10)]
    logs = [os.path.join(args.logs, n + ".mcap") for n in names]
    text = subprocess.run([binary, MAP, *logs], check=True, capture_output=True, text=True).stdout
    rows = [r for r in csv.DictReader(io.StringIO(text)) if r["label"] in ("go", "wait")]
    features = [c for c in rows[0] if c not in ("log", "track", "frame", "label")]

    ego = ["v", "v05", "v10", "v20", "vmin_so_far", "dist_line", "t_in_approach"]
    ring = ["up_arc", "up_speed", "up_eta", "up_count40", "min_eta", "near_entry", "ring_count"]

    def matrix(which, subset=None):
        chosen = [r for r in rows if r["log"] in which]
        x = np.array([[float(r[f]) for f in features] for r in chosen])
        v, d = x[:, features.index("v")], x[:, features.index("dist_line")]
        time_to_line = d / np.maximum(v, 0.3)
        derived = np.c_[time_to_line, v - x[:, features.index("v10")], v - x[:, features.index("v05")],
                        x[:, features.index("up_eta")] - time_to_line]
        y = np.array([r["label"] == "go" for r in chosen])
        if subset is not None:
            return x[:, [features.index(f) for f in subset]], y
        return np.c_[x, derived], y

    def fit_and_score(train, test, subset=None):
        x, y = matrix(train, subset)
        xt, yt = matrix(test, subset)
        model = HistGradientBoostingClassifier(max_iter=300, learning_rate=0.05, min_samples_leaf=200,
                                               l2_regularization=1.0, random_state=0).fit(x, y)
        p = model.predict(xt)
        return {
            "agreement": float(np.mean(p == yt)),
            "train_agreement": float(np.mean(model.predict(x) == y)),
            "frames": int(len(yt)),
            "human_wait_policy_go": int(np.sum(~yt & p)),
            "human_go_policy_wait": int(np.sum(yt & ~p)),
        }

    result = {"features": features, "test_008_009": fit_and_score(names[:8], names[8:]), "held_out": {}}
    r = result["test_008_009"]
    print(f"trained on FT 000-007, scored on 008-009: {100 * r['agreement']:.1f} % of {r['frames']} frames "
          f"(human wait, policy go: {r['human_wait_policy_go']}; human go, policy wait: "
          f"{r['human_go_policy_wait']}; training frames {100 * r['train_agreement']:.1f} %)")
    result["ablation_008_009"] = {}
    speeds = ["v", "v05", "v10", "v20", "vmin_so_far"]  # what [agent.task] motion_inputs gives an agent
    for label, subset in [("own motion only", ego), ("own speeds only", speeds),
                          ("own speed and distance to the line", ["v", "dist_line"]), ("ring only", ring)]:
        r = fit_and_score(names[:8], names[8:], subset)
        result["ablation_008_009"][label] = r
        print(f"  {label}: {100 * r['agreement']:.1f} %")
    # Every recording held out in turn, with all features and with the own speeds only; pooled over the ten
    # (the frames each model got right over all frames), as `replay eval` scores the agents of the same folds.
    result["held_out_speeds_only"] = {}
    for key, subset in [("held_out", None), ("held_out_speeds_only", speeds)]:
        right = frames = 0
        for held in names:
            r = fit_and_score([n for n in names if n != held], [held], subset)
            result[key][held] = r
            right += round(r["agreement"] * r["frames"])
            frames += r["frames"]
            print(f"  {key}: {held}: {100 * r['agreement']:.1f} % of {r['frames']} frames")
        result[key + "_pooled"] = right / frames
        print(f"  {key}, pooled over the ten: {100 * right / frames:.1f} % of {frames} frames")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=2)
            f.write("\n")


if __name__ == "__main__":
    main()
