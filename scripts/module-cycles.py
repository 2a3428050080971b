#!/usr/bin/env python3
"""Module cycles: files of one crate that name each other in a ring.

    python3 scripts/module-cycles.py [ROOT]

For every crate under ROOT (a directory with a Cargo.toml and a src/lib.rs or src/main.rs), each
source file of its module tree is a node, and a file has an edge to every other file of the tree
it names by a `crate::`, `super::` or `self::` path (in `use` lines or in code). A strongly
connected group of two or more files is a ring: printed with one line that names each edge,
and the exit status is 1. No ring: exit status 0.

Rings are looked for at every depth of the tree: with each module's descendants counted as
the module itself (so `brick/motor.rs -> nxt/wire.rs` and `nxt/proptests.rs -> brick/mod.rs` make
the ring `brick <-> nxt`), and file by file.

What does not count, and why:
- the crate root (lib.rs, main.rs): it declares the tree and re-exports from it, so every file
  would be in a ring with it;
- a `mod child;` declaration: the tree's structure, not one file naming another;
- comments, string literals and `$crate::` (a macro's path to its own crate).
Test modules count as any other: a test that needs a sibling's type is a sign the type belongs
lower down too.
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

IDENT = r"[A-Za-z_][A-Za-z0-9_]*"


@dataclass
class Crate:
    """One crate's module tree: module path (a tuple of names) -> file."""

    name: str
    modules: dict[tuple[str, ...], Path] = field(default_factory=dict)


def strip_comments_and_strings(text: str) -> str:
    """The source with comments, string and char literals blanked (line breaks kept)."""
    out: list[str] = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            i = j
        elif text.startswith("/*", i):
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
        elif c == "r" and re.match(r'r#*"', text[i:]) and (i == 0 or not re.match(r"[A-Za-z0-9_]", text[i - 1])):
            hashes = re.match(r"r(#*)\"", text[i:]).group(1)
            end = text.find('"' + hashes, i + 2 + len(hashes))
            end = n if end < 0 else end + 1 + len(hashes)
            out.append("\n" * text.count("\n", i, end))
            i = end
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            out.append('""' + "\n" * text.count("\n", i, j))
            i = j + 1
        elif c == "'" and re.match(r"'(\\.|[^\\'])'", text[i:i + 4] if text[i + 1:i + 2] != "\\" else text[i:i + 12]):
            m = re.match(r"'(\\[^']*|[^\\'])'", text[i:])
            i += len(m.group(0)) if m else 1
            out.append("' '")
        else:
            out.append(c)
            i += 1
    return "".join(out)


def module_tree(src: Path, root_file: Path) -> dict[tuple[str, ...], Path]:
    """Every module file of the tree rooted at `root_file`, by module path."""
    modules: dict[tuple[str, ...], Path] = {(): root_file}
    pending = [((), root_file)]
    while pending:
        path, file = pending.pop()
        text = strip_comments_and_strings(file.read_text(encoding="utf-8"))
        if path == ():
            base = src
        elif file.name == "mod.rs":
            base = file.parent
        else:
            base = file.parent / file.stem
        for m in re.finditer(r"(?m)^\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+(" + IDENT + r")\s*;", text):
            name = m.group(1)
            for candidate in (base / f"{name}.rs", base / name / "mod.rs"):
                if candidate.is_file():
                    modules[path + (name,)] = candidate
                    pending.append((path + (name,), candidate))
                    break
    return modules


def split_top_level(group: str) -> list[str]:
    """The comma-separated items of a brace group's inside, nested groups kept whole."""
    items, depth, start = [], 0, 0
    for i, c in enumerate(group):
        if c == "{":
            depth += 1
        elif c == "}":
            depth -= 1
        elif c == "," and depth == 0:
            items.append(group[start:i])
            start = i + 1
    items.append(group[start:])
    return [item.strip() for item in items if item.strip()]


def expand(path: str) -> list[list[str]]:
    """Every path a `use` tree names: `a::{b, c::d}` -> [[a, b], [a, c, d]]."""
    path = re.sub(r"\s+", "", path)
    brace = path.find("{")
    if brace < 0:
        return [[part for part in path.split("::") if part]]
    prefix = [part for part in path[:brace].split("::") if part]
    inner = path[brace + 1 : path.rfind("}")]
    return [prefix + rest for item in split_top_level(inner) for rest in expand(item)]


def inline_modules(text: str) -> list[tuple[int, int]]:
    """The (start, end) offsets of every inline `mod NAME { .. }` block of `text`."""
    blocks = []
    for m in re.finditer(r"\bmod\s+" + IDENT + r"\s*\{", text):
        depth, j = 1, m.end()
        while j < len(text) and depth:
            depth += {"{": 1, "}": -1}.get(text[j], 0)
            j += 1
        blocks.append((m.start(), j))
    return blocks


def referenced_paths(text: str) -> list[tuple[int, int, list[str]]]:
    """(line, offset, path) for every `crate::`, `super::` and `self::` path in `text`, the leading
    keyword(s) kept as the path's first parts."""
    found = []
    start = re.compile(r"(?<![A-Za-z0-9_$:])((?:crate|self|super)(?:::super)*)::")
    for m in start.finditer(text):
        j = m.end()
        # The rest of the path: identifiers, `::`, and one balanced brace group.
        rest = re.match(r"(?:" + IDENT + r"::)*(" + IDENT + r"|\{)?", text[j:])
        end = j + (rest.end() if rest else 0)
        if end > 0 and text[end - 1] == "{":
            depth, k = 1, end
            while k < len(text) and depth:
                depth += {"{": 1, "}": -1}.get(text[k], 0)
                k += 1
            end = k
        line = text.count("\n", 0, m.start()) + 1
        for path in expand(m.group(1) + "::" + text[j:end]):
            found.append((line, m.start(), path))
    return found


def resolve(crate: Crate, here: tuple[str, ...], path: list[str]) -> tuple[str, ...] | None:
    """The deepest module of the tree that `path`, written in module `here`, lands in."""
    if path[0] == "crate":
        base: tuple[str, ...] = ()
        path = path[1:]
    else:
        base = here
        while path and path[0] in ("self", "super"):
            if path[0] == "super":
                if not base:
                    return None
                base = base[:-1]
            path = path[1:]
    best = base
    for part in path:
        if base + (part,) in crate.modules:
            base = base + (part,)
            best = base
        else:
            break
    return best


def edges(crate: Crate) -> dict[tuple[str, ...], dict[tuple[str, ...], int]]:
    """For each module file, the other files it names (with the line of the first naming)."""
    graph: dict[tuple[str, ...], dict[tuple[str, ...], int]] = {m: {} for m in crate.modules}
    for module, file in crate.modules.items():
        if module == ():
            continue
        text = strip_comments_and_strings(file.read_text(encoding="utf-8"))
        text = re.sub(r"pub\(in [^)]*\)", "pub", text)
        blocks = inline_modules(text)
        for line, position, path in referenced_paths(text):
            depth = sum(1 for start, end in blocks if start <= position < end)
            # Within an inline `mod tests { .. }`, `super` first climbs back to the file.
            while depth and path and path[0] == "super":
                path, depth = path[1:], depth - 1
            if not path or path[0] not in ("crate", "self", "super"):
                path = ["self"] + path
            target = resolve(crate, module, path)
            if target is None or target == () or target == module:
                continue
            graph[module].setdefault(target, line)
    return graph


def strongly_connected(graph: dict[tuple[str, ...], dict[tuple[str, ...], int]]) -> list[list[tuple[str, ...]]]:
    """Tarjan's strongly connected components with two or more members."""
    index: dict[tuple[str, ...], int] = {}
    low: dict[tuple[str, ...], int] = {}
    on_stack: set[tuple[str, ...]] = set()
    stack: list[tuple[str, ...]] = []
    components: list[list[tuple[str, ...]]] = []
    counter = 0

    def visit(v: tuple[str, ...]) -> None:
        nonlocal counter
        index[v] = low[v] = counter
        counter += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    sys.setrecursionlimit(10_000)
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(components)


def crates(root: Path) -> list[Crate]:
    """Every crate under `root` with a library or binary module tree (target/ skipped)."""
    found = []
    for manifest in sorted(root.rglob("Cargo.toml")):
        if "target" in manifest.relative_to(root).parts:
            continue
        src = manifest.parent / "src"
        for root_name in ("lib.rs", "main.rs"):
            if (src / root_name).is_file():
                crate = Crate(str(manifest.parent.relative_to(root)) or ".")
                crate.modules = module_tree(src, src / root_name)
                found.append(crate)
                break
    return found


def collapsed(
    graph: dict[tuple[str, ...], dict[tuple[str, ...], int]], depth: int
) -> dict[tuple[str, ...], dict[tuple[str, ...], tuple[tuple[str, ...], int]]]:
    """The graph with every module cut to its first `depth` names; each edge keeps the file
    and line of one naming behind it."""
    cut: dict[tuple[str, ...], dict[tuple[str, ...], tuple[tuple[str, ...], int]]] = {}
    for v, targets in graph.items():
        cut.setdefault(v[:depth], {})
        for w, line in targets.items():
            cut.setdefault(w[:depth], {})
            if v[:depth] != w[:depth]:
                cut[v[:depth]].setdefault(w[:depth], (v, line))
    return cut


def rings(root: Path) -> list[str]:
    """One report per ring, naming each of its edges as `a -> b (file:line)`."""
    reports = []
    for crate in crates(root):
        graph = edges(crate)
        seen: set[frozenset[tuple[str, ...]]] = set()
        deepest = max(len(m) for m in crate.modules)
        for depth in range(1, deepest + 1):
            cut = collapsed(graph, depth)
            for component in strongly_connected(cut):
                if frozenset(component) in seen:
                    continue
                seen.add(frozenset(component))
                members = set(component)
                lines = [f"{crate.name}: a ring of {len(component)} modules:"]
                for v in component:
                    for w, (source, line) in sorted(cut[v].items()):
                        if w in members:
                            file = crate.modules[source].relative_to(root)
                            lines.append(f"  {'::'.join(v)} -> {'::'.join(w)}  ({file}:{line})")
                reports.append("\n".join(lines))
    return reports


def main(argv: list[str]) -> int:
    root = Path(argv[1]) if len(argv) > 1 else Path(__file__).resolve().parent.parent
    found = rings(root)
    for report in found:
        print(report)
    if found:
        print(f"{len(found)} module ring(s): move what the files share into a module both use")
        return 1
    print("no module rings")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
