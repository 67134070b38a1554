#!/usr/bin/env python3
"""Module-level import graph of a Rust crate's src/ and its cycles per top-level module.
A file src/a/b.rs or src/a/b/mod.rs is module a::b. Edges come from `crate::`, `super::`, `self::`
and child-module paths in use statements and code; re-exports (`pub use`) are followed to the
module that defines the item. Edges from inline `mod tests` blocks are marked (test) and reported
separately. A module's mod.rs counts as the module: items a child uses must not live in a mod.rs that
re-exports or uses that child. Usage: module-cycles.py SRC_DIR TOP... (e.g. src device servo server sim cli);
VERBOSE=1 names the items behind each edge. Exit status 1 when a cycle remains outside test code."""
import os, re, sys
from collections import defaultdict

VERB = os.environ.get('VERBOSE') == '1'
src = sys.argv[1]
tops = sys.argv[2:] or [None]  # no TOP: the whole crate, its root module included
files = {}  # modpath tuple -> file
for root, _, names in os.walk(src):
    for n in names:
        if not n.endswith('.rs'):
            continue
        p = os.path.join(root, n)
        rel = os.path.relpath(p, src)[:-3].split(os.sep)
        if rel[-1] == 'mod':
            rel = rel[:-1]
        if rel in (['lib'], ['main']):
            rel = []
        files[tuple(rel)] = p

def strip(text):
    out = []
    for line in text.split('\n'):
        s = re.sub(r'"(\\.|[^"\\])*"', '""', line)
        i = s.find('//')
        if i >= 0:
            s = s[:i]
        out.append(s)
    return out

def expand_use(tree):
    """'a::{b, c::{d, e}}' -> ['a::b', 'a::c::d', 'a::c::e']"""
    tree = re.sub(r'\s+as\s+\w+', '', tree)
    tree = re.sub(r'\s+', '', tree)
    def parse(s, prefix):
        res = []
        depth = 0; cur = ''; parts = []
        for ch in s:
            if ch == '{': depth += 1
            if ch == '}': depth -= 1
            if ch == ',' and depth == 0:
                parts.append(cur); cur = ''
            else:
                cur += ch
        parts.append(cur)
        for part in parts:
            if not part: continue
            m = re.match(r'^([^{]*?)(::)?\{(.*)\}$', part)
            if m and '{' in part:
                res += parse(m.group(3), prefix + ([m.group(1)] if m.group(1) else []))
            else:
                res.append('::'.join(prefix + [part]))
        return res
    return parse(tree, [])

reexports = defaultdict(dict)  # module -> name -> full path tuple (absolute)
uses = defaultdict(list)       # module -> list of (abs path tuple, is_reexport, in_test)

def absolutize(mod, segs, in_inline):
    # mod: module of the file; in_inline: depth of inline mods (their super:: points at the file)
    base = list(mod)
    i = 0
    extra = in_inline
    if segs[0] == 'crate':
        return tuple(segs[1:])
    if segs[0] == 'self':
        return tuple(base + segs[1:]) if extra == 0 else None
    if segs[0] == 'super':
        while i < len(segs) and segs[i] == 'super':
            if extra > 0:
                extra -= 1
            else:
                base = base[:-1]
            i += 1
        if extra > 0:
            return None  # still inside the file
        return tuple(base + segs[i:])
    if tuple(base + [segs[0]]) in files and extra == 0:
        return tuple(base + segs)
    return None

for mod, path in files.items():
    lines = strip(open(path).read())
    inline_stack = []  # indentation of open inline mods
    test_flag = []
    i = 0
    pending_cfg_test = False
    while i < len(lines):
        line = lines[i]
        ind = len(line) - len(line.lstrip())
        if line.strip():
            while inline_stack and ind <= inline_stack[-1] and line.strip().startswith('}'):
                inline_stack.pop(); test_flag.pop()
                break
        st = line.strip()
        if st.startswith('#[cfg(test)]'):
            pending_cfg_test = True
        m = re.match(r'^\s*(pub(\([^)]*\))?\s+)?mod\s+(\w+)\s*\{', line)
        if m:
            inline_stack.append(ind); test_flag.append(pending_cfg_test or m.group(3) == 'tests')
            pending_cfg_test = False; i += 1; continue
        if st and not st.startswith('#'):
            pending_cfg_test = False
        in_test = any(test_flag)
        depth = len(inline_stack)
        m = re.match(r'^\s*(pub(\([^)]*\))?\s+)?use\s+(.*)$', line)
        if m:
            stmt = m.group(3)
            while ';' not in stmt and i + 1 < len(lines):
                i += 1; stmt += ' ' + lines[i].strip()
            stmt = stmt.split(';')[0]
            is_pub = bool(m.group(1)) and depth == 0
            for p in expand_use(stmt):
                segs = [s for s in p.split('::') if s]
                if not segs: continue
                if segs[-1] == '*' : segs = segs[:-1]
                if not segs: continue
                if segs[-1] == 'self': segs = segs[:-1]
                a = absolutize(mod, segs, depth)
                if a is None: continue
                if is_pub:
                    reexports[mod][segs[-1]] = a
                uses[mod].append((a, is_pub, in_test))
            i += 1; continue
        for mm in re.finditer(r'(?<![:\w])([a-z_]\w*)((?:::\w+)+)', line):
            if mm.group(1) in ('crate', 'super', 'self') or depth: continue
            if tuple(list(mod) + [mm.group(1)]) in files:
                uses[mod].append((tuple(list(mod) + (mm.group(1) + mm.group(2)).split('::')), False, in_test))
        for mm in re.finditer(r'\b((?:crate|super|self)(?:::\w+)+)', line):
            segs = mm.group(1).split('::')
            a = absolutize(mod, segs, depth)
            if a is not None:
                uses[mod].append((a, False, in_test))
        i += 1

def resolve(a, seen=0):
    # longest module prefix; then item name through re-exports
    k = len(a)
    while k > 0 and tuple(a[:k]) not in files:
        k -= 1
    m = tuple(a[:k])
    if k < len(a) and seen < 10:
        name = a[k]
        if name in reexports.get(m, {}):
            return resolve(reexports[m][name], seen + 1)
    return m

def name(m):
    return '::'.join(m) or 'crate'

graph = defaultdict(dict)  # from -> to -> kinds
items = defaultdict(set)
for mod, lst in uses.items():
    for a, is_pub, in_test in lst:
        t = resolve(a)
        if t == mod: continue
        kind = 'test' if in_test else ('reexport' if is_pub else 'use')
        graph[mod].setdefault(t, set()).add(kind)
        items[(mod, t)].add(a[len(t):][:1] and a[len(t)] or '*')

def sccs(nodes, edges):
    index = {}; low = {}; stack = []; on = set(); out = []; c = [0]
    sys.setrecursionlimit(10000)
    def strong(v):
        index[v] = low[v] = c[0]; c[0] += 1; stack.append(v); on.add(v)
        for w in edges.get(v, ()):
            if w not in nodes: continue
            if w not in index:
                strong(w); low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop(); on.discard(w); comp.append(w)
                if w == v: break
            if len(comp) > 1: out.append(sorted(comp))
    for v in sorted(nodes):
        if v not in index: strong(v)
    return out

for mode in ('all', 'non-test'):
    print(f'== cycles ({mode} edges) ==')
    for top in tops:
        nodes = {m for m in files if top is None or m[:1] == (top,)}
        edges = {f: [t for t, k in ts.items() if mode == 'all' or k - {'test'}] for f, ts in graph.items()}
        for comp in sccs(nodes, edges):
            print(f'[{top or src}] cycle of {len(comp)}: ' + ', '.join(name(m) for m in comp))
            cs = set(comp)
            for f in comp:
                for t in sorted(edges.get(f, [])):
                    if t in cs:
                        print(f'    {name(f)} -> {name(t)}  ({",".join(sorted(graph[f][t]))}) ' + (' '.join(sorted(items[(f,t)])) if VERB else ''))

bad = 0
for top in tops:
    nodes = {m for m in files if top is None or m[:1] == (top,)}
    edges = {f: [t for t, k in ts.items() if k - {'test'}] for f, ts in graph.items()}
    bad += len(sccs(nodes, edges))
sys.exit(1 if bad else 0)
