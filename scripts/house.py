#!/usr/bin/env python3
"""The workspace's shape, measured from its own code: lines per crate, the largest files, the
crates' arrows (from each Cargo.toml) and the import circles between files inside each crate.

    python3 scripts/house.py                 # the figures, as Markdown tables
    python3 scripts/house.py --check         # exit 1 if any crate has files importing each other in a circle
    python3 scripts/house.py --mermaid       # the crates and their arrows, as the Mermaid graph of ARCHITECTURE.md

An import is a path a file names that resolves to another file of the same crate: `use crate::a::b`,
`super::x`, `self::y` or the same paths written inline. A name re-exported by a module (`pub use
child::Item`) resolves to the file that defines it, so a facade module that only re-exports its
children imports nothing; `mod child;` declarations are not imports. Test code is left out: `tests/`,
`benches/`, `examples/` and `#[cfg(test)]` (or `#[cfg(all(test, ...))]`) modules inside a file.
"""

import argparse
import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
IDENT = r"[A-Za-z_][A-Za-z0-9_]*"


def strip(text):
    """Source without comments, string literals and `#[cfg(test)]` modules."""
    text = re.sub(r"//[^\n]*", "", text)
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    text = re.sub(r'r#*"(?:.|\n)*?"#*', '""', text)
    text = re.sub(r'"(?:\\.|[^"\\])*"', '""', text)
    text = re.sub(r"'(?:\\.|[^'\\])'", "' '", text)
    out, i = [], 0
    test_mod = r"#\[cfg\((?:all\()?test\b[^\]]*\]\s*(?:#\[[^\]]*\]\s*)*(?:pub(?:\([a-z]+\))?\s+)?mod\s+"
    for m in re.finditer(test_mod + IDENT + r"\s*\{", text):
        if m.start() < i:
            continue
        out.append(text[i : m.start()])
        depth, j = 1, m.end()
        while j < len(text) and depth:
            depth += {"{": 1, "}": -1}.get(text[j], 0)
            j += 1
        i = j
    out.append(text[i:])
    return "".join(out)


def modules(src):
    """Module path (tuple) -> file, for one crate's src/ folder."""
    mods = {}
    for f in sorted(src.rglob("*.rs")):
        rel = f.relative_to(src).with_suffix("").parts
        if rel[-1] in ("lib", "main") and len(rel) == 1:
            path = ()
        elif rel[0] == "bin":
            continue
        elif rel[-1] == "mod":
            path = rel[:-1]
        else:
            path = rel
        mods[path] = f
    return mods


def expand_use(tree):
    """`a::{b, c::{d, e}}` -> [a::b, a::c::d, a::c::e] (each as a list of segments)."""
    tree = tree.replace(" ", "").replace("\n", "")
    depth, start, parts = 0, 0, []
    if "{" not in tree:
        return [tree.split(" as ")[0].split("::")]
    head, body = tree.split("{", 1)
    body = body[: body.rfind("}")]
    for i, ch in enumerate(body):
        if ch == "{":
            depth += 1
        elif ch == "}":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append(body[start:i])
            start = i + 1
    parts.append(body[start:])
    out = []
    for p in parts:
        if p:
            for e in expand_use(head + p):
                out.append([s for s in e if s])
    return out


def analyse(crate_dir):
    src = crate_dir / "src"
    mods = modules(src)
    code = {p: strip(f.read_text()) for p, f in mods.items()}
    defs, reexports = {}, {}
    for p, text in code.items():
        defs[p] = set(re.findall(r"\b(?:fn|struct|enum|trait|type|const|static|mod|macro_rules!)\s+(" + IDENT + ")", text))
        reexports[p] = {}
        for m in re.finditer(r"\bpub(?:\([a-z]+\))?\s+use\s+([^;]+);", text):
            for segs in expand_use(m.group(1)):
                name = segs[-1]
                if name in ("*", "self"):
                    continue
                reexports[p][name] = segs

    def absolute(p, segs):
        segs = list(segs)
        if segs[0] == "crate":
            base = []
            segs = segs[1:]
        elif segs[0] in ("self", "super"):
            base = list(p)  # `self` is this module; each `super` goes up one
            while segs and segs[0] in ("self", "super"):
                if segs[0] == "super":
                    base = base[:-1]
                segs = segs[1:]
        elif tuple([segs[0]]) in mods and mods[p].parent == src and p == ():
            base = []  # a bare path from the crate root names a child module
        else:
            return None
        return base + segs

    def resolve(path, seen=0):
        """The module file that defines what `path` (absolute segments) names."""
        if path is None or seen > 8:
            return None
        k = len(path)
        while k > 0 and tuple(path[:k]) not in mods:
            k -= 1
        mod = tuple(path[:k])
        rest = path[k:]
        if rest and rest[0] in reexports.get(mod, {}) and rest[0] not in defs[mod]:
            target = absolute(mod, reexports[mod][rest[0]])
            if target is not None:
                return resolve(target + rest[1:], seen + 1)
        return mod

    edges = {p: set() for p in mods}
    for p, text in code.items():
        # Private `use` lines of this file; `pub use` re-exports are the facade, not imports.
        paths = []
        for m in re.finditer(r"(?<![A-Za-z_])(pub(?:\([a-z]+\))?\s+)?use\s+([^;]+);", text):
            if m.group(1):
                continue
            paths += expand_use(m.group(2))
        for m in re.finditer(r"(?<![A-Za-z_:])((?:crate|super|self)(?:::" + IDENT + ")+)", text):
            paths.append(m.group(1).split("::"))
        for segs in paths:
            if not segs or segs[0] not in ("crate", "super", "self"):
                continue
            target = resolve(absolute(p, segs))
            if target is not None and target != p:
                edges[p].add(target)
    return mods, edges


def circles(edges):
    """Strongly connected components with more than one file (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(10000)
    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def crates():
    members = tomllib.loads((ROOT / "Cargo.toml").read_text())["workspace"]["members"]
    out = {}
    for name in members:
        manifest = tomllib.loads((ROOT / name / "Cargo.toml").read_text())
        deps = set(manifest.get("dependencies", {})) & set(members)
        out[name] = sorted(deps)
    return out


def lines(path):
    return sum(1 for _ in path.open())


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if a crate has an import circle")
    ap.add_argument("--mermaid", action="store_true", help="print the crate graph as Mermaid")
    ap.add_argument("--largest", type=int, default=12, help="how many of the largest files to list")
    args = ap.parse_args()
    graph = crates()
    if args.mermaid:
        sizes = {c: sum(lines(f) for f in (ROOT / c / "src").rglob("*.rs")) for c in graph}
        print("```mermaid\nflowchart BT")
        for c in graph:
            print(f'    {c}["{c}<br/>{sizes[c] / 1000:.1f}k lines"]')
        for c, deps in graph.items():
            # Only the direct arrows that no longer path implies, so the picture reads as floors.
            for d in deps:
                implied = any(d in reach(graph, e) for e in deps if e != d)
                if not implied:
                    print(f"    {c} --> {d}")
        print("```")
        return 0
    found = []
    print("| crate | lines (src) | files | uses |\n| --- | ---: | ---: | --- |")
    files = []
    for c, deps in graph.items():
        mods, edges = analyse(ROOT / c)
        n = sum(lines(f) for f in mods.values())
        files += [(lines(f), f.relative_to(ROOT)) for f in mods.values()]
        print(f"| {c} | {n:,} | {len(mods)} | {', '.join(deps) or '-'} |")
        for comp in circles(edges):
            found.append((c, [str(mods[m].relative_to(ROOT / c / 'src')) for m in comp]))
    print(f"\n| largest files | lines |\n| --- | ---: |")
    for n, f in sorted(files, reverse=True)[: args.largest]:
        print(f"| {f} | {n:,} |")
    print(f"\nimport circles inside crates: {len(found)}")
    for c, comp in found:
        print(f"- {c}: {' / '.join(comp)}")
    if args.check and found:
        print("error: files import each other in a circle (above); move what both need into one of them "
              "or into a module below both", file=sys.stderr)
        return 1
    return 0


def reach(graph, start):
    seen, todo = set(), [start]
    while todo:
        c = todo.pop()
        for d in graph.get(c, []):
            if d not in seen:
                seen.add(d)
                todo.append(d)
    return seen | {start}


if __name__ == "__main__":
    sys.exit(main())
