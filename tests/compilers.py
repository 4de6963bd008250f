"""The C compilers that generated C must build warning-free under (ISO C99, ``-Wall -Wextra -Werror
-pedantic``): GCC and Clang. A test of one that is absent is skipped, unless ``$LIEMEF_REQUIRE_COMPILERS`` names
it: CI (``.ci/run``) installs both and names both, so that a missing Clang fails there instead of passing
unseen."""

from __future__ import annotations

import os
import shutil

import pytest

COMPILERS = ("gcc", "clang")


def compiler_or_skip(cc: str) -> str:
    """The path of the compiler ``cc``; skips the test if it is absent, fails it if it is absent and required."""
    path = shutil.which(cc)
    if path is None:
        if cc in os.environ.get("LIEMEF_REQUIRE_COMPILERS", "").split():
            pytest.fail(f"{cc}: required by $LIEMEF_REQUIRE_COMPILERS but not on the PATH")
        pytest.skip(f"{cc} not on the PATH")
    return path


def warning_free_flags(cc: str, out) -> list[str]:
    """The export's flags (:data:`liemef.codegen.CFLAGS`) for a check that a source builds warning-free: GCC at
    -O1 (where its data-flow warnings run) into ``out``, Clang's front end (where all of its warnings are)."""
    from liemef import codegen

    flags = [f for f in codegen.CFLAGS if not f.startswith("-O")]
    return flags + (["-O1", "-c", "-o", str(out)] if cc == "gcc" else ["-fsyntax-only"])
