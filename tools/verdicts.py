"""Do two runs of the same studies reach the same verdicts?

    python tools/verdicts.py RUN_A RUN_B          # folders holding one folder per study

For every study folder present in both (each with its ``report.md``), prints
the verdict tables of the two runs side by side and, per row, ``same`` or
``DIFFERS``.  A row whose claim ranks costs to an error (``"to error 1e-06: …"`` or
``"split6 is the cheapest to error 1e-09"``, measured ``"a (…) < b (…) and c
(…) tie within noise < …"``) is matched by that error; two rankings agree when no pair of
candidates is ordered one way in one run and the other way in the other (a
tie within noise in either run, within a group or named across groups as
``"; ties q"``, contradicts nothing).  Exit status 1 when a
verdict differs.
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


def ranking(measured: str) -> list[set[str]] | None:
    """The groups of a ranking, cheapest first (``None``: not a ranking)."""
    measured = re.split(r"; (?:not bracketed|loaded machine)", measured)[0]  # what follows is not the ranking
    if " < " not in measured and "tie within noise" not in measured:
        return None
    groups = []
    for part in measured.split(" < "):
        names = re.findall(r"(?:^|, | and )([\w:. -]+?) \(", part.replace(" tie within noise", ""))
        groups.append({n.strip() for n in names})
    return groups


def cross_ties(measured: str) -> set[frozenset[str]]:
    """Pairs that tie across groups: ``"r (2 s, spread 0.0 %; ties q, p)"`` gives {r, q} and {r, p}."""
    found = re.findall(r"(?:^|, | and | < )([\w:.-][\w:. -]*?) \([^()]*?; ties ([^()]+)\)", measured)
    return {frozenset((n, t.strip())) for n, ts in found for t in ts.split(",")}


def rankings_agree(a: list[set[str]], b: list[set[str]], ties: set = frozenset()) -> bool:
    """No pair strictly ordered one way in ``a`` and the other way in ``b`` (a pair in ``ties`` is a tie)."""
    pos = lambda groups: {n: i for i, g in enumerate(groups) for n in g}  # noqa: E731
    pa, pb = pos(a), pos(b)
    common = [n for n in pa if n in pb]
    return not any((pa[x] - pa[y]) * (pb[x] - pb[y]) < 0 and frozenset((x, y)) not in ties
                   for x in common for y in common)


def _key(claim: str, measured: str) -> str:
    """A ranking's row is keyed by what it ranks for (``to error 1e-06``), whatever it concludes."""
    m = re.search(r"to error [0-9.e+-]+", claim) if ranking(measured) is not None else None
    return m.group(0) if m else claim


def compare(a: Path, b: Path) -> int:
    bad = 0
    for sa in sorted(p for p in a.iterdir() if (p / "report.md").is_file()):
        sb = b / sa.name
        if not (sb / "report.md").is_file():
            print(f"{sa.name}: only in {a}")
            continue
        ra, rb = ({_key(c, m): (c, m, v) for c, (m, v) in verdict_rows(s / "report.md").items()} for s in (sa, sb))
        print(f"\n## {sa.name}\n")
        print("| claim | run A measured | A | run B measured | B | |\n|---|---|---|---|---|---|")
        for key in dict.fromkeys([*ra, *rb]):
            ca, ma, va = ra.get(key, (key, "—", "missing"))
            cb, mb, vb = rb.get(key, (key, "—", "missing"))
            ga, gb = ranking(ma), ranking(mb)
            if ga is not None and gb is not None:  # a ranking: no pair ordered both ways
                same = rankings_agree(ga, gb, cross_ties(ma) | cross_ties(mb))
            else:
                same = va == vb and ca == cb
            bad += not same
            claim = ca if ca == cb else f"{ca} (B: {cb})"
            print(f"| {claim} | {ma} | {va} | {mb} | {vb} | {'same' if same else 'DIFFERS'} |")
    print(f"\n{bad} verdict(s) differ")
    return 1 if bad else 0


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    sys.exit(compare(Path(sys.argv[1]), Path(sys.argv[2])))
