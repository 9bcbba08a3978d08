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


def drop_rows_after(path: Path, step: int) -> int:
    """Remove the rows of ``path`` whose ``step`` column exceeds ``step``; returns how many were removed.

    A stretch killed between checkpoints has logged steps its checkpoint does not hold; a resume starts again from
    the checkpoint and would log those steps twice."""
    if not path.exists():
        return 0
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        fieldnames = reader.fieldnames or []
        rows = list(reader)
    kept = [row for row in rows if int(row["step"]) <= step]
    if len(kept) < len(rows):
        with path.open("w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=fieldnames)
            writer.writeheader()
            writer.writerows(kept)
    return len(rows) - len(kept)
