"""What the benchmarks report about the code they measured (shared by the benchmark scripts)."""

from __future__ import annotations

import os
import subprocess


def source_version():
    """The commit the benchmark ran on and the uncommitted files under src/ (the figures are of the working tree)."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    try:
        git = lambda *a: subprocess.run(["git", "-C", root, *a], capture_output=True, text=True,  # noqa: E731
                                        check=True).stdout
        return {"head": git("rev-parse", "--short", "HEAD").strip(),
                "src_uncommitted": [line[3:] for line in git("status", "--porcelain", "--", "src").splitlines()]}
    except (OSError, subprocess.CalledProcessError):
        return None
