"""Training logs as CSV: one row appended per call, the header written with the first row (every trainer's
``train_log.csv`` / ``val_log.csv`` / ``eval.csv``)."""

from __future__ import annotations

import csv
from pathlib import Path


def append_csv_row(path: Path, row: dict) -> None:
    """Append ``row`` to the CSV at ``path``; a new file starts with the header of ``row``'s keys."""
    new = not path.exists()
    with path.open("a", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(row))
        if new:
            writer.writeheader()
        writer.writerow(row)
