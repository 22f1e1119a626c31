"""The IOOS compliance-checker (``compliance-checker`` on PyPI) as a test helper.

:func:`cf_report` runs the checker's CF suite on a file at the CF version the
file declares in ``Conventions``, the way ``compliance-checker --test=cf:X.Y``
does, and returns its errors (high priority), warnings (medium), information
(low) and the checks that raised.  :func:`assert_cf_clean` fails on any error,
any check that raised, and any warning not in :data:`JUSTIFIED` (empty: no warning is accepted).
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import netCDF4

#: Warnings the file format accepts on purpose (section -> pattern), each with
#: its reason in docs/netcdf.md.  None today: every file must be warning-free.
JUSTIFIED: dict = {}


@dataclass
class CFReport:
    path: Path
    conventions: str
    errors: list = field(default_factory=list)      # (section, message)
    warnings: list = field(default_factory=list)
    info: list = field(default_factory=list)
    exceptions: dict = field(default_factory=dict)  # check name -> exception

    def unjustified_warnings(self) -> list:
        return [(s, m) for s, m in self.warnings if not (s in JUSTIFIED and JUSTIFIED[s].match(m))]


def _suite():
    from importlib.metadata import entry_points

    from compliance_checker.suite import CheckSuite

    if not any(k.startswith("cf:") for k in CheckSuite.checkers):
        # only the CF suites (the IOOS ones warn about their own deprecation on load)
        CheckSuite._load_checkers([e for e in entry_points(group="compliance_checker.suites")
                                   if e.name.startswith("cf")])
    return CheckSuite()


def _messages(result) -> list:
    out = list(result.msgs)
    for child in result.children:
        out += _messages(child)
    return out


def cf_report(path) -> CFReport:
    path = Path(path)
    with netCDF4.Dataset(path) as nc:
        conventions = str(getattr(nc, "Conventions", ""))
    m = re.fullmatch(r"CF-(\d+\.\d+)", conventions)
    assert m, f"{path.name}: Conventions = {conventions!r} does not name one CF version"
    checker = f"cf:{m.group(1)}"
    report = CFReport(path, conventions)
    with warnings.catch_warnings():
        # the checker's own deprecation and runtime noise is not about our files
        warnings.simplefilter("ignore")
        suite = _suite()
        assert checker in suite.checkers, f"compliance-checker has no {checker} suite"
        ds = suite.load_dataset(str(path))
        try:
            groups, errors = suite.run_all(ds, [checker], skip_checks=[])[checker]
        finally:
            ds.close()
    report.exceptions = {k: e for k, (e, _tb) in errors.items()}
    bins = {3: report.errors, 2: report.warnings, 1: report.info}
    for res in groups:
        if res.value[1] and res.value[0] < res.value[1]:
            bins[res.weight] += [(res.name, msg) for msg in _messages(res)] or [(res.name, "(no message)")]
    return report


def assert_cf_clean(path) -> CFReport:
    """0 errors, no check raised, only justified warnings; returns the report."""
    r = cf_report(path)
    assert not r.errors, f"{Path(path).name}: {r.conventions} errors: {r.errors}"
    assert not r.exceptions, f"{Path(path).name}: checks that raised: {r.exceptions}"
    bad = r.unjustified_warnings()
    assert not bad, f"{Path(path).name}: {r.conventions} warnings: {bad}"
    return r
