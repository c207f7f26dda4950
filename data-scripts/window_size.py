#!/usr/bin/env python3
"""The window's size limits (issue 29): no file under crates/app/src/gui is longer than 600 lines, and `Ready`, the
window's state once a pair is shown, has at most 10 fields. Prints what it measured; exits 1 when a limit is broken.

Usage: python3 data-scripts/window_size.py [GUI_SRC]   (default crates/app/src/gui)
"""
import os, re, sys

MAX_LINES, MAX_FIELDS = 600, 10
root = sys.argv[1] if len(sys.argv) > 1 else 'crates/app/src/gui'
bad = []
longest = (0, '')
for dp, _, fs in os.walk(root):
    for f in fs:
        if not f.endswith('.rs'):
            continue
        path = os.path.join(dp, f)
        n = sum(1 for _ in open(path, encoding='utf-8'))
        longest = max(longest, (n, path))
        if n > MAX_LINES:
            bad.append(f'{path}: {n} lines (at most {MAX_LINES})')
m = None
for dp, _, fs in os.walk(root):
    for f in fs:
        if f.endswith('.rs') and not m:
            m = re.search(r'pub struct Ready \{(.*?)\n\}', open(os.path.join(dp, f), encoding='utf-8').read(), re.S)
if not m:
    bad.append(f'{root}: no `pub struct Ready` found')
    fields = []
else:
    body = re.sub(r'//[^\n]*', '', m.group(1))
    fields = re.findall(r'^\s*(?:pub(?:\([^)]*\))?\s+)?(\w+)\s*:', body, re.M)
    if len(fields) > MAX_FIELDS:
        bad.append(f'Ready: {len(fields)} fields (at most {MAX_FIELDS}): {", ".join(fields)}')
print(f'longest file: {longest[1]} ({longest[0]} lines); Ready: {len(fields)} fields')
for b in bad:
    print('TOO BIG:', b)
sys.exit(1 if bad else 0)
