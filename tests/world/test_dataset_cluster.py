"""`plans generate --ray`: the same shards and markers as without Ray, and a rerun resumes."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

from edge_explorer.world.dataset import generate_dataset


def contents(out: Path) -> dict[str, object]:
    """Every shard's plans and every marker without its timing, by path."""
    files: dict[str, object] = {}
    for path in sorted(out.rglob("*.json*")):
        name = str(path.relative_to(out))
        if path.name.endswith(".jsonl.gz"):
            files[name] = gzip.decompress(path.read_bytes()).decode()
        else:
            files[name] = {k: v for k, v in json.loads(path.read_text()).items() if k != "seconds"}
    return files


def test_ray_writes_the_local_shards(tmp_path, ray_cluster):
    settings = {"count": 4, "dataset_seed": 2, "split_fractions": (2, 1, 1)}
    pool = generate_dataset(tmp_path / "pool", **settings, workers=1)  # in-process: no fork beside Ray's threads
    ray = generate_dataset(tmp_path / "ray", **settings, workers=1, ray="auto")
    assert ray.plans == pool.plans == 4
    assert contents(tmp_path / "ray") == contents(tmp_path / "pool") and len(contents(tmp_path / "pool")) == 7
    again = generate_dataset(tmp_path / "ray", **settings, workers=1, ray="auto")
    assert again.plans == 0 and again.shards_done_before == 3
