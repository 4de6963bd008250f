"""Every measured table of README.md and docs/ against what its command gives today (``make claims``).

A table of numbers in the docs carries, on the line before it, one of three marks (HTML comments, invisible on
the site):

- ``<!-- claim: NAME -->``: the table is a copy of the first table of the file that entry NAME of
  ``docs/claims.toml`` writes (``NAME#K``: its table K; ``NAME/FILE#K``: table K of another file of the same
  commands; a mark ending in `` (some rows)`` copies some of its rows). The entry names the commands (``{out}``
  is the claim's folder), the file, and how long it takes; ``make claims`` runs them and compares.
- ``<!-- unchecked: REASON -->``: measured, but not regenerated here (timings of one machine, another library's
  code, an external data set). It counts against the coverage.
- ``<!-- not-measured: REASON -->``: settings, definitions, a paper's printed values: nothing to regenerate.

Comparison, cell by cell: the text between numbers must be equal, integers equal, and every other number within
``units`` (default 1) of the last digit the docs print: the regenerated table prints with the same formatter, so
on one machine the cells are identical; a different BLAS may move a last digit.

    python tools/claims.py [--out out/claims] [--fast] [--check] [--coverage] [NAME ...]

``--fast`` runs only the claims of at most a minute, ``--check`` compares the outputs already in ``--out``
without running anything, ``--coverage`` prints the numbers checked against the numbers measured and exits.
Claims that need the real recordings are skipped, and say so, unless ``LIEMEF_REALDATA`` is set. Exit 1 when a
table does not match or a command fails.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import re
import shlex
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REGISTRY = ROOT / "docs" / "claims.toml"
MARK = re.compile(r"^<!--\s*(claim|unchecked|not-measured):\s*(.*?)\s*-->\s*$")
SOME_ROWS = " (some rows)"
NUMBER = re.compile(r"(?<![\w.])[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?(?![\w])")


@dataclasses.dataclass(frozen=True)
class Table:
    """A markdown table: where it is, its mark (kind, value) or None, its header and body rows as cells."""

    path: Path
    line: int
    mark: tuple[str, str] | None
    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]

    @property
    def numbers(self) -> int:
        return sum(len(NUMBER.findall(cell)) for row in self.rows for cell in row)

    @property
    def where(self) -> str:
        return f"{self.path.relative_to(ROOT) if self.path.is_relative_to(ROOT) else self.path}:{self.line}"


@dataclasses.dataclass(frozen=True)
class Claim:
    """An entry of docs/claims.toml."""

    name: str
    commands: tuple[str, ...]
    file: str
    minutes: float = 1.0
    realdata: bool = False
    units: float = 1.0

    @property
    def fast(self) -> bool:
        return self.minutes <= 1.0 and not self.realdata


def _cells(line: str) -> tuple[str, ...]:
    return tuple(c.strip() for c in line.strip().strip("|").split("|"))


def tables(path: Path) -> list[Table]:
    """The tables of a markdown file, each with the mark on the closest non-blank line before it."""
    lines = path.read_text(encoding="utf-8").splitlines()
    out, i, fenced = [], 0, False
    while i < len(lines):
        if lines[i].lstrip().startswith("```"):
            fenced = not fenced
        if not fenced and lines[i].lstrip().startswith("|") and i + 1 < len(lines) \
                and re.match(r"^\s*\|[\s:|-]+\|?$", lines[i + 1]):
            j = i + 2
            while j < len(lines) and lines[j].lstrip().startswith("|"):
                j += 1
            k = i - 1
            while k >= 0 and not lines[k].strip():
                k -= 1
            m = MARK.match(lines[k].strip()) if k >= 0 else None
            out.append(Table(path, i + 1, (m.group(1), m.group(2)) if m else None, _cells(lines[i]),
                             tuple(_cells(r) for r in lines[i + 2:j])))
            i = j
            continue
        i += 1
    return out


def doc_files() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def registry(path: Path = REGISTRY) -> dict[str, Claim]:
    """The claims of ``path``; an entry without ``command`` or ``file``, or with a key a claim does not have, is
    refused by name."""
    raw = tomllib.loads(path.read_text(encoding="utf-8"))
    keys = {"command"} | {f.name for f in dataclasses.fields(Claim)} - {"name", "commands"}
    out = {}
    for name, entry in raw.items():
        missing, unknown = {"command", "file"} - set(entry), set(entry) - keys
        if missing or unknown:
            raise ValueError(f"{path.name} [{name}]: expected the keys {sorted(keys)} with command and file, got "
                             f"{sorted(entry)}" + (f" (missing {sorted(missing)})" if missing else "")
                             + (f" (unknown {sorted(unknown)})" if unknown else ""))
        commands = entry.pop("command")
        out[name] = Claim(name, tuple([commands] if isinstance(commands, str) else commands), **entry)
    return out


def _unit(token: str) -> float:
    """One unit in the last digit that ``token`` prints."""
    mantissa, _, exponent = token.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    return 10.0 ** (int(exponent or 0) - decimals)


def cell_mismatch(doc: str, new: str, units: float = 1.0) -> str | None:
    """Why cell ``doc`` (the docs) differs from ``new`` (regenerated), or None when they agree."""
    doc_numbers, new_numbers = NUMBER.findall(doc), NUMBER.findall(new)
    if NUMBER.sub("#", doc) != NUMBER.sub("#", new) or len(doc_numbers) != len(new_numbers):
        return f"{doc!r} != {new!r}"
    for a, b in zip(doc_numbers, new_numbers, strict=True):
        exact = not re.search(r"[.eE]", a)
        if (float(a) != float(b)) if exact else abs(float(a) - float(b)) > units * _unit(a) * (1 + 1e-9):
            return f"{a} != {b} in {doc!r} against {new!r}"
    return None


def mismatches(doc: Table, new: Table, units: float = 1.0, rows: str = "all") -> list[str]:
    """Every difference between a docs table and its regenerated one; rows are matched by their first cell."""
    if doc.header != new.header:
        return [f"header {doc.header} != {new.header}"]
    out = []
    if rows == "all" and [r[0] for r in doc.rows] != [r[0] for r in new.rows]:
        out.append(f"rows {[r[0] for r in doc.rows]} != {[r[0] for r in new.rows]}")
    by_key = {}
    for r in new.rows:
        by_key.setdefault(r[0], []).append(r)
    seen: dict[str, int] = {}
    for r in doc.rows:
        n = seen[r[0]] = seen.get(r[0], -1) + 1
        if len(by_key.get(r[0], ())) <= n:
            out.append(f"row {r[0]!r} is not in the regenerated table")
            continue
        other = by_key[r[0]][n]
        if len(r) != len(other):
            out.append(f"row {r[0]!r}: {len(r)} cells against {len(other)}")
            continue
        for col, a, b in zip(doc.header + ("",) * len(r), r, other, strict=False):
            why = cell_mismatch(a, b, units)
            if why:
                out.append(f"row {r[0]!r}, column {col!r}: {why}")
    return out


def parse_claim(mark: str) -> tuple[str, str | None, int, bool]:
    """A claim mark's value ``NAME[/FILE][#K][ (some rows)]``: the claim's name, the file of its output (None:
    the claim's own), the index of the table in that file and whether the docs copy only some of its rows."""
    some = mark.endswith(SOME_ROWS)
    rest, _, index = mark.removesuffix(SOME_ROWS).partition("#")
    name, _, file = rest.partition("/")
    return name, file or None, int(index or 0), some


def marked() -> dict[str, list[Table]]:
    """The docs' claim tables, by claim name."""
    out: dict[str, list[Table]] = {}
    for path in doc_files():
        for t in tables(path):
            if t.mark and t.mark[0] == "claim":
                out.setdefault(parse_claim(t.mark[1])[0], []).append(t)
    return out


def coverage() -> tuple[int, int, int]:
    """Numbers in claim tables, in unchecked (or unmarked) tables, and in not-measured tables."""
    counts = {"claim": 0, "unchecked": 0, "not-measured": 0}
    for path in doc_files():
        for t in tables(path):
            counts[t.mark[0] if t.mark else "unchecked"] += t.numbers
    return counts["claim"], counts["unchecked"], counts["not-measured"]


def _argv(command: str, out: Path) -> list[str]:
    argv = shlex.split(command.replace("{out}", str(out)))
    bindir = Path(sys.executable).parent
    if argv[0] == "liemef":
        argv[0] = str(bindir / "liemef")
    elif argv[0] == "python":
        argv[0] = sys.executable
    return argv


def regenerate(claim: Claim, out: Path) -> None:
    """Run the claim's commands with ``{out}`` set to ``out`` (each command replaces what it wrote before)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT / "src"),
                                                                   os.environ.get("PYTHONPATH")])))
    for command in claim.commands:
        subprocess.run(_argv(command, out), cwd=ROOT, env=env, check=True, stdout=subprocess.DEVNULL)


def check(claim: Claim, out: Path, docs: list[Table]) -> list[str]:
    """The mismatches of every docs table of ``claim`` against the table it copies in ``out``."""
    problems = []
    for t in docs:
        _, file, index, some = parse_claim(t.mark[1])
        path = out / (file or claim.file)
        found = tables(path) if path.exists() else []
        if len(found) <= index:
            state = f"has {len(found)} tables" if path.exists() else "was not written"
            problems.append(f"{t.where}: {path} {state}, the claim reads table {index}")
            continue
        problems += [f"{t.where}: {m}" for m in mismatches(t, found[index], claim.units,
                                                           "subset" if some else "all")]
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help="claims to run (default: all)")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "claims")
    parser.add_argument("--fast", action="store_true", help="only the claims of at most a minute")
    parser.add_argument("--check", action="store_true", help="compare the outputs in --out; run nothing")
    parser.add_argument("--coverage", action="store_true", help="print the coverage and exit")
    args = parser.parse_args(argv)
    if args.coverage:
        checked, unchecked, _ = coverage()
        print(f"{checked} of {checked + unchecked} measured numbers in the docs' tables are checked "
              f"({100 * checked / (checked + unchecked):.0f} %)")
        return 0
    claims, docs = registry(), marked()
    unknown = sorted(set(args.names) - set(claims))
    if unknown:
        parser.error(f"no claim named {', '.join(unknown)}; the claims are {', '.join(sorted(claims))}")
    failed = 0
    for name in args.names or sorted(claims):
        claim = claims[name]
        if args.fast and not claim.fast:
            continue
        if claim.realdata and not os.environ.get("LIEMEF_REALDATA"):
            print(f"{name}: skipped, it needs the real recordings (set LIEMEF_REALDATA)", file=sys.stderr)
            continue
        out = args.out / name
        if not args.check:
            print(f"{name}: running (about {claim.minutes:g} min)", file=sys.stderr, flush=True)
            try:
                regenerate(claim, out)
            except subprocess.CalledProcessError as err:
                print(f"{name}: FAILED, {shlex.join(err.cmd)} exited with {err.returncode}")
                failed += 1
                continue
        problems = check(claim, out, docs.get(name, []))
        print(f"{name}: {'ok' if not problems else f'{len(problems)} mismatches'} "
              f"({sum(t.numbers for t in docs.get(name, []))} numbers)")
        for p in problems:
            print(f"  {p}")
        failed += bool(problems)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
