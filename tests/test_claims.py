"""The docs' tables against the commands that make them (``tools/claims.py``, ``make claims``).

Every table of numbers in README.md and docs/ is marked: a claim (a copy of what an entry of docs/claims.toml
writes), unchecked (measured, not regenerated here, with the reason) or not measured (settings, definitions).
The claims of at most a minute are regenerated and compared here; ``make test-slow`` regenerates the rest
(those on the real recordings when ``LIEMEF_REALDATA`` is set).
"""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import claims  # noqa: E402

REGISTRY = claims.registry()
MARKED = claims.marked()


def test_every_table_of_numbers_is_marked():
    unmarked = [t.where for p in claims.doc_files() for t in claims.tables(p) if t.numbers and t.mark is None]
    assert not unmarked, f"tables with numbers but no claim/unchecked/not-measured mark: {unmarked}"


def test_every_claim_is_in_the_registry_and_every_entry_is_claimed():
    assert sorted(MARKED) == sorted(REGISTRY)


@pytest.mark.parametrize("name", sorted(REGISTRY))
def test_each_page_names_the_command_of_its_claim(name):
    """The liemef commands of a claim, with its folder written DIR, are on the page of each of its tables (a
    script that only assembles their outputs into one table need not be)."""
    for table in MARKED[name]:
        text = " ".join(table.path.read_text(encoding="utf-8").replace("\\\n", " ").split())
        for command in (c for c in REGISTRY[name].commands if c.startswith("liemef ")):
            shown = " ".join(re.sub(r"\{out\}\S*", "DIR", command).split())
            assert shown in text, f"{table.where} does not name the command `{shown}` of its claim"


def test_a_changed_number_or_word_is_a_mismatch():
    assert claims.cell_mismatch("1.111 [0.474, 1.975]", "1.111 [0.474, 1.975]") is None
    assert claims.cell_mismatch("1.111", "1.112") is None                 # one unit in the last printed digit
    assert claims.cell_mismatch("1.111", "1.113") is not None
    assert claims.cell_mismatch("8.8e5", "8.9e5") is None
    assert claims.cell_mismatch("8.8e5", "9.0e5") is not None
    assert claims.cell_mismatch("2/5 failed", "3/5 failed") is not None   # integers are exact
    assert claims.cell_mismatch("49.5 (far above!)", "49.5 (above)") is not None
    assert claims.cell_mismatch("0.693", "0.693 (far above!)") is not None
    assert claims.cell_mismatch("1.111", "1.113", units=2) is None


def _table(text: str, tmp_path: Path) -> claims.Table:
    path = tmp_path / "t.md"
    path.write_text(text)
    (table,) = claims.tables(path)
    return table


def test_a_table_is_compared_row_by_row(tmp_path):
    new = _table("| filter | rms |\n|---|---:|\n| mef | 1.0 |\n| iekf | 2.0 |\n", tmp_path)
    assert claims.mismatches(_table("| filter | rms |\n|---|---:|\n| mef | 1.0 |\n| iekf | 2.0 |\n", tmp_path),
                             new) == []
    assert claims.mismatches(_table("| filter | rms |\n|---|---:|\n| mef | 1.0 |\n| iekf | 2.2 |\n", tmp_path),
                             new) == ["row 'iekf', column 'rms': 2.2 != 2.0 in '2.2' against '2.0'"]
    subset = _table("| filter | rms |\n|---|---:|\n| iekf | 2.0 |\n", tmp_path)
    assert claims.mismatches(subset, new, rows="subset") == []
    assert claims.mismatches(subset, new) != []
    assert claims.mismatches(_table("| filter | RMS |\n|---|---:|\n| mef | 1.0 |\n", tmp_path), new) != []


def test_marks_are_read_before_indented_tables_and_not_inside_code(tmp_path):
    text = ("- a list\n\n  <!-- claim: x -->\n\n  | a | b |\n  |---|---|\n  | r | 1 |\n\n"
            "```\n| c | d |\n|---|---|\n| r | 2 |\n```\n")
    path = tmp_path / "t.md"
    path.write_text(text)
    (table,) = claims.tables(path)
    assert table.mark == ("claim", "x") and table.rows == (("r", "1"),)


def test_a_registry_entry_with_a_wrong_key_is_refused_by_name(tmp_path):
    path = tmp_path / "claims.toml"
    path.write_text('[x]\ncommand = "liemef compare localization --out {out}"\nfile = "a.md"\nrows = "subset"\n')
    with pytest.raises(ValueError, match=r"claims.toml \[x\].*unknown \['rows'\]"):
        claims.registry(path)
    path.write_text('[y]\ncommand = "liemef compare localization --out {out}"\n')
    with pytest.raises(ValueError, match=r"\[y\].*missing \['file'\]"):
        claims.registry(path)


def test_the_coverage_is_reported():
    checked, unchecked, _ = claims.coverage()
    assert checked > 0 and checked + unchecked > checked


def _regenerate_and_compare(name: str, tmp_path: Path) -> None:
    claim = REGISTRY[name]
    if claim.realdata and not os.environ.get("LIEMEF_REALDATA"):
        pytest.skip("needs the real recordings (LIEMEF_REALDATA)")
    claims.regenerate(claim, tmp_path / name)
    problems = claims.check(claim, tmp_path / name, MARKED[name])
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("name", sorted(n for n, c in REGISTRY.items() if c.fast))
def test_fast_claims_match_their_commands(name, tmp_path):
    _regenerate_and_compare(name, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(n for n, c in REGISTRY.items() if not c.fast))
def test_slow_claims_match_their_commands(name, tmp_path):
    _regenerate_and_compare(name, tmp_path)
