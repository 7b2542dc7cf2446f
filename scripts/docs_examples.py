#!/usr/bin/env python3
"""Runs the shell examples of README.md and docs/*.md as written, in a fresh clone (Python 3 stdlib only).

Every ```sh block of those pages carries a marker on the line before it, which says whether it runs:

    <!-- example: run -->            runs here (seconds to a few minutes)
    <!-- example: long -->           runs with --long (the main job, trainings: tens of minutes to hours)
    <!-- example: skip: REASON -->   never run here (a cluster, a GPU, a viewer, an install)

A block without a marker is an error, so a new example has to say what it is. The blocks that run are
run in page order (README.md first, then docs/ by name), each with `bash -euo pipefail` in the root of a
fresh `git clone` of this repository (HEAD: commit first) that sits beside a link to ../shared, so the
paths in the examples (`data/osm/...`, `../shared/data/...`, `runs/...`) mean what they mean to a user.
`pipeline` is the binary given with --pipeline (default target/release/pipeline), first on PATH; a line
`cargo run --release -p pipeline -- ARGS` runs that binary with ARGS instead of building it again (any
other cargo command runs cargo).

    python3 scripts/docs_examples.py [--pipeline target/release/pipeline] [--long] [--only PAGE]
        [--keep DIR] [--timeout 1800]

Prints one line per block (page, line, marker, seconds, result) and exits non-zero when a block that
ran failed (its output is shown) or a block has no marker.
"""
import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MARKER = re.compile(r"^<!-- example: (run|long|skip)(?::\s*(.*?))?\s*-->$")

# Runs `cargo run --release -p pipeline -- ARGS` as the given binary; other cargo commands as cargo.
CARGO_SHIM = """
cargo() {
    if [ "$1" = run ] && [ "$2" = --release ] && [ "$3" = -p ] && [ "$4" = pipeline ] && [ "$5" = -- ]; then
        shift 5
        pipeline "$@"
    else
        command cargo "$@"
    fi
}
"""


def pages():
    return [ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))


def blocks(page):
    """(line number, marker, reason, text) of every ```sh block of `page`."""
    lines = page.read_text().splitlines()
    found = []
    i = 0
    while i < len(lines):
        if lines[i].strip() == "```sh":
            start = i + 1
            j = start
            while j < len(lines) and lines[j].strip() != "```":
                j += 1
            before = lines[i - 1].strip() if i > 0 else ""
            m = MARKER.match(before)
            found.append((start, m.group(1) if m else None, (m.group(2) or "") if m else "", "\n".join(lines[start:j])))
            i = j + 1
        else:
            i += 1
    return found


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--pipeline", default=str(ROOT / "target/release/pipeline"))
    parser.add_argument("--long", action="store_true", help="also run the blocks marked long")
    parser.add_argument("--only", help="only this page (e.g. docs/maps.md)")
    parser.add_argument("--keep", help="clone into this folder and keep it (default: a temporary one)")
    parser.add_argument("--timeout", type=float, default=1800, help="seconds a block may take")
    args = parser.parse_args()

    binary = Path(args.pipeline).resolve()
    if not binary.is_file():
        sys.exit(f"error: {args.pipeline}: no such binary\nhint: cargo build --release -p pipeline, or give --pipeline")
    shared = (ROOT.parent / "shared").resolve()

    todo = []
    unmarked = []
    for page in pages():
        name = str(page.relative_to(ROOT))
        if args.only and name != args.only:
            continue
        for line, marker, reason, text in blocks(page):
            if marker is None:
                unmarked.append(f"{name}:{line}")
            todo.append((name, line, marker, reason, text))
    if unmarked:
        sys.exit("error: ```sh blocks without an <!-- example: run|long|skip: REASON --> marker: " + ", ".join(unmarked))

    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="docs_examples_"))
    work.mkdir(parents=True, exist_ok=True)
    clone = work / "repo"
    if clone.exists():
        shutil.rmtree(clone)
    subprocess.run(["git", "clone", "--quiet", str(ROOT), str(clone)], check=True)
    link = work / "shared"
    if not link.exists() and shared.is_dir():
        link.symlink_to(shared)
    bin_dir = work / "bin"
    bin_dir.mkdir(exist_ok=True)
    shim = bin_dir / "pipeline"
    if shim.exists() or shim.is_symlink():
        shim.unlink()
    shim.symlink_to(binary)
    env = dict(os.environ, PATH=f"{bin_dir}:{os.environ.get('PATH', '')}")
    env.pop("RERUN", None)

    failed = []
    ran = 0
    for name, line, marker, reason, text in todo:
        where = f"{name}:{line}"
        if marker == "skip" or (marker == "long" and not args.long):
            why = reason if marker == "skip" else "long: run with --long"
            print(f"{where:<28} {marker:<5} -      not run ({why})", flush=True)
            continue
        started = time.time()
        try:
            done = subprocess.run(
                ["bash", "-euo", "pipefail", "-c", CARGO_SHIM + text],
                cwd=clone, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                timeout=args.timeout,
            )
            code, out = done.returncode, done.stdout + done.stderr
        except subprocess.TimeoutExpired as e:
            code, out = "timeout", f"{e}"
        seconds = time.time() - started
        ran += 1
        if code == 0:
            print(f"{where:<28} {marker:<5} {seconds:6.1f} s passed", flush=True)
        else:
            failed.append(where)
            print(f"{where:<28} {marker:<5} {seconds:6.1f} s FAILED ({code})\n{text}\n---- output\n{out[-4000:]}", flush=True)
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    print(f"examples: {ran - len(failed)} passed, {len(failed)} failed")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
