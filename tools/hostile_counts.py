"""Count tests/test_hostile.py's cases per category (issue 19's closing note).

A category is a section of the file, opened by a comment line ``# --- name ---``; a case is a collected test
(each parametrization counts). Prints one line per category and the total:

    PYTHONPATH=src python tools/hostile_counts.py [tests/test_hostile.py]
"""

from __future__ import annotations

import ast
import collections
import re
import subprocess
import sys


def counts(path: str = "tests/test_hostile.py") -> dict[str, int]:
    """The number of collected cases per section of ``path``, in the order of the sections."""
    text = open(path, encoding="utf-8").read()
    sections = [(i + 1, re.sub(r"^# -+ | -+$", "", line).strip())
                for i, line in enumerate(text.splitlines()) if line.startswith("# ---")]
    line_of = {n.name: n.lineno for n in ast.parse(text).body if isinstance(n, ast.FunctionDef)}
    ids = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", path],
                         capture_output=True, text=True, check=True).stdout.split()
    out = collections.Counter({name: 0 for _, name in sections})
    for nid in (i for i in ids if "::" in i):
        fn = nid.split("::")[1].split("[")[0]
        out[max((s for s in sections if s[0] < line_of[fn]), default=(0, "(before any section)"))[1]] += 1
    return dict(out)


if __name__ == "__main__":
    table = counts(*sys.argv[1:])
    for name, n in table.items():
        print(f"{n:4d}  {name}")
    print(f"{sum(table.values()):4d}  total")
