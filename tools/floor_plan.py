#!/usr/bin/env python3
"""Print the module import graph's cycles and its imports that run up the floors.

    python3 tools/floor_plan.py [--src src] [--edges] [--with-tests] [--big]

A module is one source file (`src/scene/value.rs` is `scene/value`, `src/scene/usda/mod.rs` is
`scene/usda`). An edge A -> B is a `crate::…`, `super::…` or `self::…` path in A's code (use
declarations and inline paths; comments and string literals are ignored) that names B or an item
of B. `#[cfg(test)]` code is left out unless `--with-tests` is given: a unit test may drive a
stage from above. A path to an item a folder's `mod.rs` re-exports (`pub use child::Item`) is an edge to the
child that defines it, since re-exports are aliases, not code of their own.

Floors, from the ground up (a module may import its own floor and the ones below it):

    ground: diag, input, abi, runtime, stack
    front -> scene -> compose -> ir -> backend -> render -> session -> view -> tools (cli, bench, fuzz, plot)

Top-level modules not named here are reported as unplaced. Exit status is 1 when there is a cycle
or an upward import, so the script can gate a commit.
"""

import argparse
import os
import re
import sys
from collections import defaultdict

GROUND = {"diag", "input", "abi", "runtime", "stack"}
STAGES = ["front", "scene", "compose", "ir", "backend", "render", "session", "view"]
TOOLS = {"cli", "bench", "fuzz", "main"}


def floor_of(module):
    """Floor number of a module (0 is the ground); None when its top-level name is unplaced."""
    top = module.split("/")[0]
    if top in GROUND:
        return 0
    if top in STAGES:
        return 1 + STAGES.index(top)
    if top in TOOLS:
        return 1 + len(STAGES)
    return None


def floor_name(n):
    return "ground" if n == 0 else (STAGES[n - 1] if n <= len(STAGES) else "tools")


def strip_code(text):
    """Blank out comments, string literals and char literals, keeping line structure."""
    out = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            i = j
            continue
        if text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append("\n" * text.count("\n", i, j))
            i = j
            continue
        raw = re.match(r'b?r(#*)"', text[i : i + 260])
        if raw and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            end = '"' + raw.group(1)
            j = text.find(end, i + raw.end())
            j = n if j < 0 else j + len(end)
            out.append('""' + "\n" * text.count("\n", i, j))
            i = j
            continue
        if c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            out.append('""' + "\n" * text.count("\n", i, j))
            i = j + 1
            continue
        if c == "'":
            m = re.match(r"'(\\[^']{1,10}|[^\\'])'", text[i : i + 14])
            if m:
                out.append("' '")
                i += m.end()
                continue
        out.append(c)
        i += 1
    return "".join(out)


def strip_test_code(code):
    """Blank out `#[cfg(test)]` items (an inline module, function or use declaration)."""
    out = code
    for m in reversed(list(re.finditer(r"#\[cfg\(test\)\]", code))):
        i = m.end()
        # The item ends at its first top-level `;` or at the `}` closing its first `{`.
        depth, j = 0, i
        while j < len(code):
            if code[j] == "{":
                depth += 1
            elif code[j] == "}":
                depth -= 1
                if depth == 0:
                    j += 1
                    break
            elif code[j] == ";" and depth == 0:
                j += 1
                break
            j += 1
        out = out[: m.start()] + re.sub(r"[^\n]", " ", out[m.start() : j]) + out[j:]
    return out


def test_only_children(code, module):
    """Child modules a file declares under `#[cfg(test)]` (`#[cfg(test)] mod tests;`)."""
    prefix = module + "/" if module else ""
    return {prefix + m.group(1) for m in re.finditer(r"#\[cfg\(test\)\]\s*(?:pub\s+)?mod\s+([A-Za-z_][A-Za-z0-9_]*)\s*;", code)}


def expand_use_tree(tree):
    """`a::{b, c::{d, e}}` -> [[a, b], [a, c, d], [a, c, e]] (`self` keeps its prefix)."""
    tree = re.sub(r"\s+", "", tree)

    def parse(s, pos):
        # Returns (list of paths, new pos); stops at ',' or '}' at this level.
        prefix = []
        while pos < len(s):
            m = re.match(r"[A-Za-z_][A-Za-z0-9_]*|\*", s[pos:])
            if m:
                prefix.append(m.group(0))
                pos += m.end()
                if s.startswith("::", pos):
                    pos += 2
                    if s.startswith("{", pos):
                        pos += 1
                        paths = []
                        while pos < len(s) and s[pos] != "}":
                            sub, pos = parse(s, pos)
                            paths += [prefix + p for p in sub]
                            if pos < len(s) and s[pos] == ",":
                                pos += 1
                        return paths, pos + 1
                    continue
                if s.startswith("as", pos):
                    m2 = re.match(r"as[A-Za-z_][A-Za-z0-9_]*", s[pos:])
                    pos += m2.end() if m2 else 0
                return [[p for p in prefix if p != "self"] if prefix[-1] == "self" else prefix], pos
            pos += 1
        return [prefix], pos

    paths, _ = parse(tree, 0)
    return [p for p in paths if p]


class Crate:
    def __init__(self, src, with_tests):
        self.src = src
        self.with_tests = with_tests
        self.files = {}  # module id -> file path
        for root, _, names in os.walk(src):
            for name in names:
                if not name.endswith(".rs"):
                    continue
                path = os.path.join(root, name)
                rel = os.path.relpath(path, src)[:-3]
                if rel in ("lib", "main"):
                    continue
                mod = rel[: -len("/mod")] if rel.endswith("/mod") else rel
                self.files[mod] = path
        self.reexports = {}  # module -> {item name: child module}
        self.test_only = set()
        for mod, path in self.files.items():
            code = strip_code(open(path, encoding="utf-8").read())
            self.test_only |= test_only_children(code, mod)
            table = {}
            for m in re.finditer(r"\bpub\s+use\s+([^;]+);", code):
                for p in expand_use_tree(m.group(1)):
                    child = (mod + "/" if mod else "") + p[0]
                    if p[0] in ("crate", "super", "self"):
                        continue
                    if child in self.files and len(p) >= 2:
                        table[p[-1]] = child
            self.reexports[mod] = table

    def is_folder(self, mod):
        return self.files.get(mod, "").endswith("mod.rs")

    def resolve(self, segments):
        """Module that a crate-absolute path (without `crate`) names, or None."""
        mod = ""
        i = 0
        while i < len(segments) and ((mod + "/" if mod else "") + segments[i]) in self.files:
            mod = (mod + "/" if mod else "") + segments[i]
            i += 1
        if not mod:
            return None
        # An item a folder re-exports from one of its children belongs to that child.
        while i < len(segments) and segments[i] in self.reexports.get(mod, {}):
            mod = self.reexports[mod][segments[i]]
            i += 1
        return mod

    def absolute(self, module, inline_depth, path):
        """Turn a `crate::`/`super::`/`self::` path into crate-absolute segments."""
        own = module.split("/") if module else []
        # Inside an inline `mod tests { … }` the file module is `super`.
        base = own + ["<inline>"] * inline_depth
        if path[0] == "crate":
            return path[1:]
        if path[0] not in ("self", "super"):
            return None
        cur = list(base)
        rest = list(path)
        if rest[0] == "self":
            rest = rest[1:]
        while rest and rest[0] == "super":
            cur = cur[:-1]
            rest = rest[1:]
        cur = [c for c in cur if c != "<inline>"]
        return cur + rest

    def edges(self):
        graph = defaultdict(lambda: defaultdict(list))  # a -> b -> [line numbers]
        for mod, path in sorted(self.files.items()):
            code = strip_code(open(path, encoding="utf-8").read())
            if not self.with_tests:
                if any(mod == t or mod.startswith(t + "/") for t in self.test_only):
                    continue
                code = strip_test_code(code)
            depth_at = inline_module_depths(code)
            paths = []
            for m in re.finditer(r"\buse\s+((?:crate|super|self)\b[^;]*);", code):
                for p in expand_use_tree(m.group(1)):
                    paths.append((m.start(), p))
            for m in re.finditer(r"(?<![A-Za-z0-9_:])((?:crate|super|self)(?:::[A-Za-z_][A-Za-z0-9_]*)+)", code):
                prev = code[max(0, m.start() - 200) : m.start()]
                if re.search(r"\buse\s+[^;]*$", prev):
                    continue  # part of a use declaration, already expanded
                paths.append((m.start(), m.group(1).split("::")))
            for pos, p in paths:
                absolute = self.absolute(mod, depth_at(pos), p)
                if absolute is None:
                    continue
                target = self.resolve(absolute)
                if target is None or target == mod:
                    continue
                # A folder's own children are its code; a child naming its folder's items is not
                # a cycle unless the folder's code names the child back (then both edges count).
                if (mod + "/") in (target + "/")[: len(mod) + 1] and target.startswith(mod + "/") and not self.is_folder(mod):
                    continue
                graph[mod][target].append(code.count("\n", 0, pos) + 1)
        return graph


def inline_module_depths(code):
    """Function from a position to how many inline `mod name {` blocks enclose it."""
    starts = []
    stack = []
    depth_changes = []  # (pos, depth)
    depth = 0
    mod_open = set(m.end() - 1 for m in re.finditer(r"\bmod\s+[A-Za-z_][A-Za-z0-9_]*\s*\{", code))
    for i, c in enumerate(code):
        if c == "{":
            is_mod = i in mod_open
            stack.append(is_mod)
            if is_mod:
                depth += 1
                depth_changes.append((i, depth))
        elif c == "}" and stack:
            if stack.pop():
                depth -= 1
                depth_changes.append((i, depth))
    del starts

    def at(pos):
        d = 0
        for p, dd in depth_changes:
            if p > pos:
                break
            d = dd
        return d

    return at


def cycles(graph, nodes):
    """Strongly connected components with more than one module (Tarjan), each with one cycle."""
    index, low, on, stack, out = {}, {}, set(), [], []
    counter = [0]
    sys.setrecursionlimit(10000)

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, {}):
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

    for v in sorted(nodes):
        if v not in index:
            visit(v)
    return out


def one_cycle(graph, comp):
    """A shortest cycle through the component's first module, for the report."""
    members = set(comp)
    start = comp[0]
    prev = {start: None}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph.get(v, {})):
                if w not in members:
                    continue
                if w == start:
                    path = [v]
                    while prev[path[-1]] is not None:
                        path.append(prev[path[-1]])
                    return list(reversed(path)) + [start]
                if w not in prev:
                    prev[w] = v
                    nxt.append(w)
        frontier = nxt
    return comp


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--src", default=os.path.join(os.path.dirname(__file__), "..", "src"))
    ap.add_argument("--edges", action="store_true", help="print every edge")
    ap.add_argument("--with-tests", action="store_true", help="count #[cfg(test)] code too")
    ap.add_argument("--big", action="store_true", help="list the files over 1000 lines")
    args = ap.parse_args()
    crate = Crate(os.path.normpath(args.src), args.with_tests)
    graph = crate.edges()
    nodes = set(crate.files)

    if args.edges:
        for a in sorted(graph):
            for b in sorted(graph[a]):
                print(f"{a} -> {b}  (line {', '.join(map(str, graph[a][b][:5]))})")

    comps = cycles(graph, nodes)
    print(f"modules: {len(nodes)}, edges: {sum(len(v) for v in graph.values())}")
    print(f"cycles: {len(comps)}")
    for comp in comps:
        print("  " + " -> ".join(one_cycle(graph, comp)) + (f"   (component: {', '.join(comp)})" if len(comp) > 2 else ""))

    upward = []
    unplaced = sorted({m.split("/")[0] for m in nodes if floor_of(m) is None})
    for a in sorted(graph):
        for b in sorted(graph[a]):
            fa, fb = floor_of(a), floor_of(b)
            if fa is not None and fb is not None and fb > fa:
                upward.append((a, b, graph[a][b]))
    print(f"upward imports: {len(upward)}")
    for a, b, lines in upward:
        print(f"  {a} ({floor_name(floor_of(a))}) -> {b} ({floor_name(floor_of(b))})  src/{a} line {lines[0]}")
    if unplaced:
        print(f"unplaced top-level modules (no floor): {', '.join(unplaced)}")
    if args.big:
        for mod, path in sorted(crate.files.items()):
            n = sum(1 for _ in open(path, encoding="utf-8"))
            if n > 1000:
                print(f"  over 1000 lines: {os.path.relpath(path, args.src)} ({n})")
    return 1 if comps or upward else 0


if __name__ == "__main__":
    sys.exit(main())
