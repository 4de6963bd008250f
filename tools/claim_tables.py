"""Tables of the docs that put several commands' outputs side by side, made from those outputs.

Each function reads what the commands of its claim in ``docs/claims.toml`` wrote under one folder and writes one
markdown table there, which ``tools/claims.py`` compares with the docs' copy:

    python tools/claim_tables.py NAME DIR
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from liemef.studies.compare._common import fmt


def second_order_scale(folder: Path) -> str:
    """The mean NEES of the quadrotor rows of ``liemef compare second-order`` from the drawn initial errors
    scaled by 1, 0.5 and 0 (``{folder}/s1``, ``s05``, ``s0``)."""
    runs = {scale: json.loads((folder / sub / "metrics.json").read_text())
            for scale, sub in (("1", "s1"), ("0.5", "s05"), ("0", "s0"))}
    filters = ("mef-hold-safe", "mef-first-hold", "iekf", "ukf-m")
    lines = ["| system | S | default (`mef-hold-safe`) | `mef-first-hold` | `iekf` | `ukf-m` |",
             "|---|---:|---:|---:|---:|---:|"]
    for system in runs["1"]["cases"]:
        for scale, result in runs.items():
            row = result["cases"][system]["filters"]
            lines.append(f"| `{system}` | {scale} | "
                         + " | ".join(fmt(row[f]["nees"], 3) for f in filters) + " |")
    return "\n".join(lines) + "\n"


TABLES = {"second-order-scale": (second_order_scale, "scale.md")}


if __name__ == "__main__":
    name, folder = sys.argv[1], Path(sys.argv[2])
    make, file = TABLES[name]
    (folder / file).write_text(make(folder))
