#!/usr/bin/env python3
"""Import circles between the source files of one crate.

Each non-test source file of the crate is a node; a file imports another
when it names an item under `crate::…` (or `super::…`, `self::…`) that the
other file defines as a module. Prints every strongly connected set of
more than `--max` files (default 2) and exits 1 when there is one.

    scripts/import-cycles.py worker/src            # the worker's circles
    scripts/import-cycles.py worker/src --max 1    # every circle, pairs too
"""

import argparse
import os
import re
import sys


def modules(src):
    """Module path (tuple) -> file, for every .rs file under `src`."""
    out = {}
    for root, _, files in os.walk(src):
        for f in files:
            if not f.endswith(".rs"):
                continue
            path = os.path.join(root, f)
            rel = os.path.relpath(path, src)[:-3].split(os.sep)
            if rel[-1] in ("mod", "lib", "main"):
                rel = rel[:-1]
            out[tuple(rel)] = path
    return out


def strip_tests(text):
    """The file without its `#[cfg(test)] mod tests { … }` block."""
    i = text.find("#[cfg(test)]\nmod tests")
    return text if i < 0 else text[:i]


PATH = re.compile(r"\b(crate|super|self)((?:::[A-Za-z_][A-Za-z0-9_]*)+)")


ITEM = re.compile(
    r"^\s*(?:pub(?:\([^)]*\))?\s+)?(?:async\s+|unsafe\s+|const\s+)*"
    r"(?:struct|enum|fn|const|static|type|trait|mod|union)\s+([A-Za-z_][A-Za-z0-9_]*)",
    re.M,
)
REEXPORT = re.compile(r"\bpub(?:\([^)]*\))?\s+use\s+([^;]*);", re.S)
BARE = re.compile(r"(?<![:\w])([a-z_][a-z0-9_]*)((?:::[A-Za-z_][A-Za-z0-9_]*)+)")


def expand(path):
    """`a::b::{c, d::e}` -> ["a::b::c", "a::b::d::e"] (one level of braces)."""
    path = re.sub(r"\s+", "", path)
    m = re.match(r"^(.*?)::\{(.*)\}$", path)
    if not m:
        return [path]
    out, depth, cur = [], 0, ""
    for ch in m.group(2):
        if ch == "," and depth == 0:
            out.append(cur)
            cur = ""
            continue
        depth += ch == "{"
        depth -= ch == "}"
        cur += ch
    out.append(cur)
    return [m.group(1) + "::" + x for x in out if x]


def graph(src):
    mods = modules(src)
    texts, reexports = {}, {}
    for me, path in mods.items():
        text = strip_tests(open(path, encoding="utf-8").read())
        texts[me] = re.sub(r"//[^\n]*", "", text)
        # Names this module re-exports, and the path each comes from.
        reexports[me] = {}
        for group in REEXPORT.findall(texts[me]):
            for full in expand(group):
                full = full.split(" as ")[0]
                reexports[me][full.split("::")[-1]] = full

    def resolve(me, path, seen=()):
        """The module file a path names from module `me`: the longest
        prefix that is a module, followed through its re-exports."""
        parts = [p for p in path.split("::") if p]
        if not parts:
            return None
        head = parts[0]
        if head == "crate":
            base, parts = (), parts[1:]
        elif head == "self":
            base, parts = me, parts[1:]
        elif head == "super":
            base, parts = me[:-1], parts[1:]
            while parts and parts[0] == "super":
                base, parts = base[:-1], parts[1:]
        elif me + (head,) in mods:
            base = me
        else:
            return None
        for n in range(len(parts), -1, -1):
            cand = base + tuple(parts[:n])
            if cand in mods:
                rest = parts[n:]
                if rest and rest[0] in reexports.get(cand, {}) and (cand, rest[0]) not in seen:
                    return resolve(cand, reexports[cand][rest[0]], seen + ((cand, rest[0]),))
                return cand
        return None

    edges = {m: set() for m in mods}
    for me in mods:
        text = texts[me]
        paths = [h + r for h, r in PATH.findall(text)]
        paths += [h + r for h, r in BARE.findall(text)]
        for use in re.findall(r"\buse\s+([^;]*);", text, re.S):
            paths += expand(use)
        for p in paths:
            target = resolve(me, p.split(" as ")[0])
            # A folder's mod.rs declaring or re-exporting its children is
            # not an import of them: only the files that define items count.
            if target is not None and target != me and target != ():
                edges[me].add(target)
    return mods, edges


def sccs(edges):
    """Tarjan's strongly connected components."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
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
            out.append(comp)

    sys.setrecursionlimit(10000)
    for v in edges:
        if v not in index:
            visit(v)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src", help="a crate's src folder")
    ap.add_argument("--max", type=int, default=2, help="largest circle allowed, in files")
    a = ap.parse_args()
    mods, edges = graph(a.src)
    bad = [c for c in sccs(edges) if len(c) > a.max]
    circles = [c for c in sccs(edges) if len(c) > 1]
    for c in circles:
        names = sorted(mods[m] for m in c)
        mark = "TOO LARGE" if len(c) > a.max else "allowed"
        print(f"circle of {len(c)} files ({mark}): {' '.join(names)}")
    if not circles:
        print(f"{a.src}: no import circles")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
