#!/usr/bin/env python3
"""Stack frame of every function of a Cortex-M ELF, read from its prologue.

    stack_frames.py ELF            # the largest frames
    stack_frames.py OLD.ELF NEW.ELF  # the largest frames of NEW beside OLD's, and what grew

A frame is what the prologue reserves: 4 bytes per register in `push`/`stmdb sp!`, 4 or 8 per
register in `vpush` (s or d registers), plus every `sub sp, …, #imm` among the first 40
instructions. Names drop their `::h<hash>` suffix so two builds can be compared. The stack
high-water mark of a run is the deepest chain of these frames (plus interrupt frames); this
tool says which frames a change made larger, not which chain is deepest.
Needs `llvm-objdump` (Debian's `llvm` package).
"""
import re
import subprocess
import sys

PROLOGUE = 40


def registers(args):
    m = re.search(r"\{(.*)\}", args)
    if not m:
        return 0, False
    n = 0
    for r in m.group(1).split(","):
        r = r.strip()
        if "-" in r:
            a, b = (x.strip() for x in r.split("-"))
            n += int(b[1:]) - int(a[1:]) + 1
        elif r:
            n += 1
    return n, "d" in m.group(1)


def frames(elf):
    out = subprocess.run(
        ["llvm-objdump", "-d", "--no-show-raw-insn", "-C", elf],
        capture_output=True, text=True, check=True,
    ).stdout
    res, cur, size, seen = {}, None, 0, 0
    for line in out.splitlines():
        m = re.match(r"^[0-9a-f]+ <(.*)>:$", line)
        if m:
            if cur:
                res[cur] = max(res.get(cur, 0), size)
            cur, size, seen = re.sub(r"::h[0-9a-f]{16}$", "", m.group(1)), 0, 0
            continue
        fields = line.split("\t")
        if cur is None or len(fields) < 3:
            continue
        seen += 1
        if seen > PROLOGUE:
            continue
        op, args = fields[1].strip(), fields[2].strip()
        if op.startswith("push") or (op.startswith("stmdb") and args.startswith("sp!")):
            size += 4 * registers(args)[0]
        elif op.startswith("vpush"):
            n, double = registers(args)
            size += (8 if double else 4) * n
        elif op.startswith("sub") and args.startswith("sp"):
            imm = re.search(r"#(0x[0-9a-f]+|\d+)", args)
            if imm:
                size += int(imm.group(1), 0)
    if cur:
        res[cur] = max(res.get(cur, 0), size)
    return res


def main(argv):
    if len(argv) not in (2, 3):
        sys.exit(__doc__)
    new = frames(argv[-1])
    old = frames(argv[1]) if len(argv) == 3 else {}
    print("bytes   before  function")
    for name, s in sorted(new.items(), key=lambda kv: -kv[1])[:25]:
        print(f"{s:6d}  {old.get(name, '-')!s:>6}  {name[:100]}")
    if old:
        print("\ngrew    now     function")
        grew = sorted(((s - old.get(n, 0), n) for n, s in new.items()), reverse=True)
        for g, n in grew[:12]:
            if g > 0:
                print(f"{g:+6d}  {new[n]:6d}  {n[:100]}")


if __name__ == "__main__":
    main(sys.argv)
