#!/usr/bin/env python3
"""Picks a small seed set from a grown fuzz corpus (fuzz/corpus/README.md).

    python3 scripts/fuzz-pick-seeds.py CONTROL_FILE MAX_FILES MAX_BYTES

CONTROL_FILE is the -merge_control_file of a libFuzzer merge: per input, the edges it covers
(COV lines). Greedy set cover: repeatedly take the input adding the most edges not yet covered
(the smaller on a tie) while the byte budget allows. Prints the chosen paths; a summary goes to
stderr.
"""
import sys, os
ctl, n_max, budget = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
lines = open(ctl).read().split('\n')
n = int(lines[0]); files = lines[2:2+n]
cov = {}; ft = {}
for l in lines[2+n:]:
    p = l.split()
    if not p: continue
    if p[0] == 'COV': cov[int(p[1])] = set(p[2:])
    if p[0] == 'FT': ft[int(p[1])] = set(p[2:])
allcov = set().union(*cov.values()) if cov else set()
size = {i: os.path.getsize(files[i]) for i in cov}
chosen, have, used = [], set(), 0
while len(chosen) < n_max:
    best = None
    for i, c in cov.items():
        if i in chosen or used + size[i] > budget: continue
        gain = len(c - have)
        if gain == 0: continue
        score = (gain, -size[i])
        if best is None or score > best[0]: best = (score, i)
    if not best: break
    i = best[1]; chosen.append(i); have |= cov[i]; used += size[i]
    print(f"{files[i]}\t{size[i]}\t+{best[0][0]}", file=sys.stderr)
print(f"edges {len(have)}/{len(allcov)} bytes {used}", file=sys.stderr)
for i in chosen: print(files[i])
