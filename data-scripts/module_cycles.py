#!/usr/bin/env python3
"""Import cycles among the modules of one crate.

Usage: python3 data-scripts/module_cycles.py CRATE_SRC [--tests] [--private MOD] [--skip MOD] [-v]

Builds the module graph of CRATE_SRC (e.g. crates/gpu/src) from the `crate::`, `$crate::`, `super::` and `self::`
paths of every file (comments and string literals left out; `#[cfg(test)]` modules only with --tests) and a parent's
`use child::…`, then prints each strongly connected component of more than one module as `CYCLE: …` and a summary
line. Exits 1 when there is a cycle. `--private MOD` also exits 1 when a module outside MOD's subtree imports anything in
it (the crate root may declare it); `--skip MOD` leaves MOD's subtree out of the cycle search. A `main.rs` beside a
`lib.rs` is its own crate (it reaches the library by name) and is not read. `-v` prints every edge. It reads paths as text, so an import written without a
path (a glob from the prelude, a macro) is not seen; open the code at the names it prints before believing a cycle.
"""
import os, re, sys
root = sys.argv[1] if len(sys.argv) > 1 else 'crates/gpu/src'
mods = {}  # module path tuple -> file
for dp, _, fs in os.walk(root):
    for f in fs:
        if not f.endswith('.rs'): continue
        rel = os.path.relpath(os.path.join(dp, f), root)[:-3].split(os.sep)
        if rel == ['main'] and os.path.exists(os.path.join(root, 'lib.rs')): continue
        if rel in (['lib'], ['main']): rel = []
        elif rel[-1] == 'mod': rel = rel[:-1]
        mods[tuple(rel)] = os.path.join(dp, f)
def strip(src):
    src = re.sub(r'/\*.*?\*/', '', src, flags=re.S)
    src = re.sub(r'//[^\n]*', '', src)
    # raw strings first (r"…", r#"…"#), then char literals that hold a quote, then ordinary strings, which may span
    # lines and continue with `\` + newline (hence re.S: without it `\\.` does not match the newline)
    src = re.sub(r'\br(#*)"(.*?)"\1', '""', src, flags=re.S)
    src = re.sub(r"'(?:\\.|[^'\\\n])'", "' '", src)
    src = re.sub(r'"(?:\\.|[^"\\])*"', '""', src, flags=re.S)
    return src
def cfg_test_blocks(src):
    out, i = [], 0
    for m in re.finditer(r'#\[cfg\(test\)\]\s*(?:#\[[^\]]*\]\s*)*mod\s+\w+\s*\{', src):
        if m.start() < i: continue
        depth = 1; j = m.end()
        while depth and j < len(src):
            depth += {'{': 1, '}': -1}.get(src[j], 0); j += 1
        out.append(src[m.end():j-1]); i = j
    return out
def cfg_test_strip(src):
    # drop `#[cfg(test)] mod tests { ... }` blocks: test-only code is not part of the library's import graph
    out, i = [], 0
    for m in re.finditer(r'#\[cfg\(test\)\]\s*(?:#\[[^\]]*\]\s*)*mod\s+\w+\s*\{', src):
        if m.start() < i: continue
        out.append(src[i:m.start()]); depth = 1; j = m.end()
        while depth and j < len(src):
            depth += {'{': 1, '}': -1}.get(src[j], 0); j += 1
        i = j
    out.append(src[i:]); return ''.join(out)
include_tests = '--tests' in sys.argv
def resolve(cur, segs, seen=()):
    # longest prefix of segs that is a known module; a name that module only re-exports (`pub use x::Y`) resolves to
    # where Y is defined, since naming `crate::Result` depends on `error`, not on the crate root's code
    best = None
    for k in range(len(segs), -1, -1):
        if tuple(segs[:k]) in mods: best = tuple(segs[:k]); break
    if best is not None and k < len(segs) and (best, segs[k]) in reexports and (best, segs[k]) not in seen:
        return resolve(cur, list(reexports[(best, segs[k])]) + segs[k + 1:], seen + ((best, segs[k]),))
    return best
def path_base(m, head):
    if head in ('crate', '$crate'): return []
    if head == 'super': return list(m[:-1])
    if head == 'self': return list(m)
    return list(m) + [head] if m + (head,) in mods else None  # a child module, or an outside crate (None)
def use_leaves(prefix, body):
    # `a::b::{C, d::E as F}` -> [(['a','b','C'], 'C'), (['a','b','d','E'], 'F')]
    body = body.strip()
    brace = body.find('{')
    if brace < 0:
        m_ = re.match(r'([\w:]+?)(?:\s+as\s+(\w+))?\s*$', body)
        if not m_: return []
        segs = [x for x in m_.group(1).split('::') if x]
        if not segs or segs[-1] == 'self': segs = segs[:-1]
        return [(prefix + segs, m_.group(2) or (segs[-1] if segs else None))] if segs else []
    head = [x for x in body[:brace].split('::') if x]
    inner = body[brace + 1:body.rfind('}')]
    parts, d, cur_ = [], 0, ''
    for ch in inner:
        d += {'{': 1, '}': -1}.get(ch, 0)
        if ch == ',' and d == 0: parts.append(cur_); cur_ = ''
        else: cur_ += ch
    parts.append(cur_)
    out = []
    for p_ in parts:
        if p_.strip() == 'self': out.append((prefix + head, head[-1] if head else None))
        elif p_.strip(): out += use_leaves(prefix + head, p_)
    return out
reexports = {}  # (module, name) -> path (list of segments, from the crate root) that the name stands for
for m, f in mods.items():
    src = cfg_test_strip(strip(open(f).read()))
    for mt in re.finditer(r'\bpub(?:\([\w: ]+\))?\s+use\s+([^;]+);', src):
        body = re.sub(r'\s+', ' ', mt.group(1)).strip()
        first = re.match(r'(\$?\w+)', body).group(1)
        base = path_base(m, first)
        if base is None or first.startswith('$') and False: continue
        rest = body[len(first):].lstrip(':')
        for segs, name in use_leaves(base, rest):
            if name and name != '*': reexports[(m, name)] = tuple(segs)
edges = {m: set() for m in mods}
def scan(m, src, super_base):
    # expand `use a::{b, c::{d}}` roughly: collect path heads
    for mt in re.finditer(r'\b(\$?crate|super|self)((?:::\w+)+|::\{)', src):
        head = mt.group(1); tail = src[mt.start(2):]
        # read path segments
        segs = re.match(r'((?:::\w+)*)', tail).group(1).split('::')[1:]
        brace = re.match(r'(?:::\w+)*::\{', tail)
        if head in ('crate', '$crate'): base = []
        elif head == 'super': base = list(super_base)
        else: base = list(m)
        # further leading `super::` segments
        while segs and segs[0] == 'super': base = base[:-1]; segs = segs[1:]
        targets = []
        if brace:
            # items inside braces: top-level names
            start = mt.start(2) + brace.end(); depth = 1; j = start
            while depth: depth += {'{':1,'}':-1}.get(src[j],0); j += 1
            inner = src[start:j-1]
            # split top-level by comma
            parts, d, cur_ = [], 0, ''
            for ch in inner:
                if ch == '{': d += 1
                if ch == '}': d -= 1
                if ch == ',' and d == 0: parts.append(cur_); cur_ = ''
                else: cur_ += ch
            parts.append(cur_)
            for p in parts:
                p = p.strip()
                if not p: continue
                sub = re.match(r'(\w+(?:::\w+)*)', p)
                if sub: targets.append(base + segs + [s for s in sub.group(1).split('::') if s != 'self'])
        else:
            targets.append(base + segs)
        for t in targets:
            r = resolve(m, t)
            if r is not None and r != m and not (len(r) > len(m) and r[:len(m)] == m and False):
                edges[m].add(r)
for m, f in mods.items():
    full = strip(open(f).read())
    scan(m, cfg_test_strip(full), m[:-1])
    if include_tests:
        for block in cfg_test_blocks(full): scan(m, block, m)
# a parent declaring `mod child` does not by itself depend on it, but `pub use child::X` does (found above via self::/bare)
for m, f in mods.items():
    src = strip(open(f).read())
    if not include_tests: src = cfg_test_strip(src)
    for mt in re.finditer(r'\buse\s+(\w+)::', src):
        name = mt.group(1)
        if name in ('crate', 'super', 'self', 'std', 'core'): continue
        if m + (name,) in mods: edges[m].add(m + (name,))
    for mt in re.finditer(r'\b(\w+)::\w', src):
        name = mt.group(1)
        if m + (name,) in mods and m + (name,) != m: edges[m].add(m + (name,))
def opt(flag):
    return tuple(sys.argv[sys.argv.index(flag) + 1].split('::')) if flag in sys.argv else None
private, skip = opt('--private'), opt('--skip')
within = lambda m, sub: m[:len(sub)] == sub
leaks = []
if private:
    for m in sorted(edges):
        if m != () and not within(m, private):
            leaks += [(m, t) for t in sorted(edges[m]) if within(t, private)]
if skip:
    edges = {m: {t for t in e if not within(t, skip)} for m, e in edges.items() if not within(m, skip)}
# Tarjan
idx, low, st, on, out, n = {}, {}, [], set(), [], [0]
sys.setrecursionlimit(10000)
def sc(v):
    idx[v] = low[v] = n[0]; n[0] += 1; st.append(v); on.add(v)
    for w in edges[v]:
        if w not in idx: sc(w); low[v] = min(low[v], low[w])
        elif w in on: low[v] = min(low[v], idx[w])
    if low[v] == idx[v]:
        comp = []
        while True:
            w = st.pop(); on.discard(w); comp.append(w)
            if w == v: break
        out.append(comp)
for v in edges:
    if v not in idx: sc(v)
name = lambda m: '::'.join(m) or 'crate'
cyc = [c for c in out if len(c) > 1]
if '-v' in sys.argv:
    for m in sorted(edges): print(f'{name(m)} -> {", ".join(sorted(name(x) for x in edges[m]))}')
for c in cyc: print('CYCLE:', ', '.join(sorted(name(m) for m in c)))
for m, t in leaks: print(f'PRIVATE: {name(m)} imports {name(t)}')
print(f'{len(mods)} modules, {sum(len(e) for e in edges.values())} edges, {len(cyc)} cycle(s)'
      + (f', {len(leaks)} import(s) of {name(private)} from outside it' if private else ''))
sys.exit(1 if cyc or leaks else 0)
