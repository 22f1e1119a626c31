"""Do two runs of the same studies reach the same verdicts?

    python tools/verdicts.py RUN_A RUN_B          # folders holding one folder per study

For every study folder present in both (each with its ``report.md``), prints
the verdict tables of the two runs side by side and, per row, ``same`` or
``DIFFERS``; a ranking stated in one run and a tie within noise in the
other counts as agreement only where the report says "tie" (the measured
spread covered the gap).  Exit status 1 when a verdict differs.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path


def verdict_rows(report: Path) -> dict[str, tuple[str, str]]:
    """``{claim: (measured, verdict)}`` of a report's verdict table."""
    lines = report.read_text().splitlines()
    try:
        start = lines.index("### Verdicts")
    except ValueError:
        return {}
    out = {}
    for ln in lines[start + 1:]:
        if ln.startswith("### ") or ln.startswith("**"):
            break
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", ln)[1:-1]]
        if len(cells) == 4 and cells[0] not in ("claim", "---"):
            out[cells[0]] = (cells[1], cells[3])
    return out


def compare(a: Path, b: Path) -> int:
    bad = 0
    for sa in sorted(p for p in a.iterdir() if (p / "report.md").is_file()):
        sb = b / sa.name
        if not (sb / "report.md").is_file():
            print(f"{sa.name}: only in {a}")
            continue
        ra, rb = verdict_rows(sa / "report.md"), verdict_rows(sb / "report.md")
        print(f"\n## {sa.name}\n")
        print("| claim | run A measured | A | run B measured | B | |\n|---|---|---|---|---|---|")
        for claim in dict.fromkeys([*ra, *rb]):
            ma, va = ra.get(claim, ("—", "missing"))
            mb, vb = rb.get(claim, ("—", "missing"))
            same = va == vb or ("tie" in (ma + mb).lower() and "missing" not in (va, vb))
            bad += not same
            print(f"| {claim} | {ma} | {va} | {mb} | {vb} | {'same' if same else 'DIFFERS'} |")
    print(f"\n{bad} verdict(s) differ")
    return 1 if bad else 0


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    sys.exit(compare(Path(sys.argv[1]), Path(sys.argv[2])))
