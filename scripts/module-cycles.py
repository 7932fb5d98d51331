#!/usr/bin/env python3
"""Reports import cycles between the modules of each crate in the workspace.

    scripts/module-cycles.py [CRATE_SRC_DIR ...]

With no argument it checks every `src/` folder of the workspace's members. Exit status 1 if
any crate has a cycle, 0 otherwise.

What counts: module A depends on module B when code in A (any file of A's subtree, outside
`#[cfg(test)]` code) names a path into B: `use crate::b::…`, `crate::b::X` in an expression,
`super::b::…`, or a grouped `use crate::{b::X, c}`. Dependencies are compared between
siblings: at each level of the module tree, the children of one parent form a graph, and a
cycle among them (A uses B and B uses A, directly or through other siblings) is reported. A
child using its parent's items (`super::X`) is not a cycle: the parent is the module the
child belongs to. The crate root (lib.rs, main.rs) only declares and re-exports, and is not
part of any graph.

Test code is left out (files named tests.rs or under a tests/ folder of a module, and lines
from a `#[cfg(test)]` line to the end of a file): tests may reach across modules without
making the production code cyclic.
"""

import os
import re
import sys
from collections import defaultdict

WORD = r"[A-Za-z_][A-Za-z0-9_]*"


def module_of(src, path):
    """The module path of a source file, as a tuple: src/a/b.rs and src/a/b/mod.rs are (a, b)."""
    rel = os.path.relpath(path, src)[:-3].split(os.sep)
    if rel[-1] == "mod":
        rel = rel[:-1]
    if rel in (["lib"], ["main"]) or (len(rel) >= 1 and rel[0] == "bin"):
        return ()
    return tuple(rel)


def strip(text):
    """Drops comments, string and char literals, and test code from a file's text."""
    cut = re.search(r"^\s*#\[cfg\(test\)\]", text, re.M)
    if cut:
        text = text[: cut.start()]
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        nxt = text[i + 1] if i + 1 < n else ""
        if c == "/" and nxt == "/":
            while i < n and text[i] != "\n":
                i += 1
        elif c == "/" and nxt == "*":
            depth, i = 1, i + 2
            while i < n and depth:
                if text.startswith("/*", i):
                    depth, i = depth + 1, i + 2
                elif text.startswith("*/", i):
                    depth, i = depth - 1, i + 2
                else:
                    i += 1
        elif c == "r" and (nxt == '"' or nxt == "#") and not (i and re.match(r"\w", text[i - 1])):
            j = i + 1
            while j < n and text[j] == "#":
                j += 1
            if j < n and text[j] == '"':
                close = '"' + "#" * (j - i - 1)
                end = text.find(close, j + 1)
                i = n if end < 0 else end + len(close)
                out.append('""')
            else:
                out.append(c)
                i += 1
        elif c == '"':
            i += 1
            while i < n and text[i] != '"':
                i += 2 if text[i] == "\\" else 1
            i += 1
            out.append('""')
        elif c == "'":
            # A char literal ('x', '\n', '\u{..}') or a lifetime ('a): only the former is skipped.
            m = re.match(r"'(?:\\.[^']*|[^\\'])'", text[i:])
            if m:
                i += m.end()
                out.append("' '")
            else:
                out.append(c)
                i += 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def expand(tree):
    """The paths of a use tree's text, e.g. `crate::{a::X, b::{c, d}}`."""
    tree = tree.replace(" ", "").replace("\n", "")
    out = []

    def walk(prefix, t):
        # Split the top level of t at commas outside braces.
        depth, start, parts = 0, 0, []
        for i, ch in enumerate(t):
            if ch == "{":
                depth += 1
            elif ch == "}":
                depth -= 1
            elif ch == "," and depth == 0:
                parts.append(t[start:i])
                start = i + 1
        parts.append(t[start:])
        for part in parts:
            if not part:
                continue
            brace = part.find("{")
            if brace >= 0 and part.endswith("}"):
                walk(prefix + part[:brace], part[brace + 1 : -1])
            else:
                out.append(prefix + part.split(" as ")[0])

    walk("", tree)
    return out


def references(module, text):
    """The absolute module paths (tuples) that code in `module` names."""
    paths = []
    for m in re.finditer(r"\buse\s+([^;]+);", text):
        paths.extend(expand(m.group(1)))
    for m in re.finditer(r"\b((?:crate|super|self)(?:::" + WORD + r")+)", text):
        paths.append(m.group(1))
    out = []
    for p in paths:
        segs = [s for s in p.split("::") if s]
        if not segs:
            continue
        if segs[0] == "crate":
            out.append(tuple(segs[1:]))
        elif segs[0] in ("super", "self"):
            base = list(module)
            while segs and segs[0] in ("super", "self"):
                if segs[0] == "super" and base:
                    base.pop()
                segs = segs[1:]
            out.append(tuple(base + segs))
    return out


def cycles(graph):
    """Strongly connected components of more than one node (Tarjan)."""
    index, low, on, stack, found = {}, {}, set(), [], []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
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
                found.append(sorted(comp))

    for v in list(graph):
        if v not in index:
            visit(v)
    return found


def check(src):
    modules = {}
    for root, dirs, files in os.walk(src):
        for f in files:
            if not f.endswith(".rs"):
                continue
            path = os.path.join(root, f)
            mod = module_of(src, path)
            if mod == () or mod[-1] == "tests" or "tests" in mod[:-1]:
                continue
            with open(path, encoding="utf-8") as fh:
                modules.setdefault(mod, []).append(strip(fh.read()))
    known = set(modules)
    # Every prefix of a module is a module (a folder's mod.rs may be absent in 2018 layout).
    for mod in list(known):
        for i in range(1, len(mod)):
            known.add(mod[:i])

    def resolve(path):
        """The deepest known module that `path` lies in."""
        for i in range(len(path), 0, -1):
            if path[:i] in known:
                return path[:i]
        return None

    # Sibling graphs: for each parent, edges between its children.
    graphs = defaultdict(lambda: defaultdict(set))
    for mod, texts in modules.items():
        for text in texts:
            for ref in references(mod, text):
                target = resolve(ref)
                if target is None:
                    continue
                # The nearest common parent of mod and target, and the children under it.
                common = 0
                while common < min(len(mod), len(target)) and mod[common] == target[common]:
                    common += 1
                if common == len(mod) or common == len(target):
                    continue  # one contains the other: parent and child
                parent = mod[:common]
                a, b = mod[: common + 1], target[: common + 1]
                graphs[parent][a].add(b)
                graphs[parent].setdefault(b, set())
    found = []
    for parent, graph in graphs.items():
        for comp in cycles(graph):
            found.append(["::".join(m) for m in comp])
    return found


def members(top):
    dirs = []
    for name in sorted(os.listdir(top)):
        src = os.path.join(top, name, "src")
        if os.path.isfile(os.path.join(top, name, "Cargo.toml")) and os.path.isdir(src):
            dirs.append(src)
    return dirs


def main():
    top = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    dirs = sys.argv[1:] or members(top)
    bad = False
    for src in dirs:
        found = check(src)
        crate = os.path.relpath(os.path.dirname(os.path.abspath(src)), top)
        if found:
            bad = True
            for comp in found:
                print(f"{crate}: cycle among {', '.join(comp)}")
        else:
            print(f"{crate}: no module cycle")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
