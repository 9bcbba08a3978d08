"""Shipping the map predictor: copy a run's best weights into ``models/predictor/`` and write its model card.

``card.json`` holds what a user of the weights needs to trust them: the architecture and input encoding, MACs and
parameters, how it was trained (command, data, steps, epochs, wall time, hardware), its evaluation figures, the
single-thread fp32 latency measured on this host, and the SHA-256 of the weights file (checked before loading).
"""

from __future__ import annotations

import json
import platform
import shutil
from pathlib import Path

import torch

from edge_explorer.backends.card import sha256_of
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.learn.hardware import torch_latency_ms
from edge_explorer.learn.unet import UNet, count_macs_params, load_unet
from edge_explorer.mapping.ego import PREDICTOR_WINDOW_CELLS
from edge_explorer.predict import encoding
from edge_explorer.predict.predictor import ENVELOPE_KEY

CARD_FORMAT = "edge-explorer/model-card"
WEIGHTS_NAME = "predictor.safetensors"


def predictor_latency_ms(model: UNet, repeats: int = 30, threads: int = 1) -> dict:
    """Median / p90 wall time of one 256×256 prediction (batch 1, fp32, ``threads`` torch threads)."""
    x = torch.zeros(1, model.config.in_channels, PREDICTOR_WINDOW_CELLS, PREDICTOR_WINDOW_CELLS)
    return torch_latency_ms(lambda: model(x), repeats, threads)


def training_stretches(run_dir: Path) -> list[dict]:
    """Every stretch of training behind ``run_dir``'s weights, oldest first: a fine-tuning run's ``init_weights``
    leads back to the run it started from, and each run's state.json lists where its own stretches ran."""
    stretches: list[dict] = []
    seen: set[Path] = set()
    while run_dir is not None and run_dir.resolve() not in seen and (run_dir / "state.json").exists():
        seen.add(run_dir.resolve())
        state = json.loads((run_dir / "state.json").read_text())
        config = json.loads((run_dir / "config.json").read_text())
        own = state.get("stretches") or [
            {"from_step": 0, "to_step": state["step"], "wall_s": round(state["wall_s"], 1), "hardware": "not recorded"}
        ]
        batch = config["batch_size"]
        for stretch in reversed(own):
            samples = (stretch["to_step"] - stretch["from_step"]) * batch
            entry = {"run": str(run_dir), "train_data": config["train_data"], "samples": samples, **stretch}
            stretches.insert(0, entry)
        init = config.get("init_weights") or ""
        run_dir = Path(init).parent if init else None
    return stretches


def ship_predictor(
    run_dir: Path, out_dir: Path, evaluations: dict[str, Path], command: str, whole_floors: bool = False
) -> dict:
    """Copy ``run_dir/best.safetensors`` to ``out_dir`` and write ``card.json``; returns the card.

    ``evaluations`` maps a name (``test``, ``realplans``) to the JSON of ``edge-explorer eval predictor``, which
    must have scored these very weights. ``whole_floors``: the model also learned whole floors, so the card's
    ``envelope_m`` is null (no envelope, :func:`edge_explorer.predict.predictor.card_envelope_m`); otherwise the card
    leaves it out (the 21 × 11 m plans' envelope).
    """
    best = run_dir / "best.safetensors"
    if not best.exists():
        raise EdgeExplorerError(f"{run_dir}: no best.safetensors; train first")
    state = json.loads((run_dir / "state.json").read_text())
    config = json.loads((run_dir / "config.json").read_text())
    weights_sha = sha256_of(best)
    metrics = {}
    for name, path in evaluations.items():
        report = json.loads(path.read_text())
        if report.get("model_sha256") != weights_sha:
            raise EdgeExplorerError(f"{path} evaluated another model (sha256 differs from {best})")
        metrics[name] = {key: report[key] for key in ("plans", "n_plans", "explorer", "seed", "thresholds", "levels")}

    stretches = training_stretches(run_dir)
    model = load_unet(best)
    macs, params = count_macs_params(model)
    out_dir.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(best, out_dir / WEIGHTS_NAME)
    train_samples = state["train_set_size"]
    card = {
        "format": CARD_FORMAT,
        "model": "map predictor (U-Net)",
        "weights": WEIGHTS_NAME,
        "sha256": weights_sha,
        "architecture": {
            "class": "edge_explorer.learn.unet.UNet",
            "config": model.config.to_dict(),
            "ops": ["Conv2d (+bias, BatchNorm folded)", "ReLU", "nearest Upsample x2", "concat", "sigmoid"],
            "macs": macs,
            "params": params,
        },
        "input": {
            "shape": [1, encoding.INPUT_CHANNELS, PREDICTOR_WINDOW_CELLS, PREDICTOR_WINDOW_CELLS],
            "dtype": "float32",
            "encoding": "edge_explorer.predict.encoding.encode_windows: channel 0 = observed FREE, channel 1 = "
            "observed OCCUPIED (0/1); north-up 0.20 m ego window of mapping.ego.pad_shift, robot cell (128, 128)",
        },
        "output": {
            "shape": [1, encoding.OUTPUT_CHANNELS, PREDICTOR_WINDOW_CELLS, PREDICTOR_WINDOW_CELLS],
            "meaning": "P(occupied) per cell, sigmoid applied; threshold with predict.thresholding (t_f_max 0.04, "
            "t_o 0.94)",
        },
        "training": {
            "command": command,
            "config": config,
            "data": {"train_samples": train_samples, "train_dir": config["train_data"], "val_dir": config["val_data"]},
            "steps": state["step"],
            "samples_seen": state["samples"],
            "epochs": state["samples"] / train_samples,
            "best_step": state["best_step"],
            "best_val_score": state["best_score"],
            "selection": "best mean val F1 over the 50-80 %, 80-95 % and >= 95 % coverage bins",
            "wall_time_h": state["wall_s"] / 3600,
            "stretches": stretches,
            "samples_seen_all_stretches": sum(x["samples"] for x in stretches),
            "wall_time_h_all_stretches": sum(x["wall_s"] for x in stretches) / 3600,
            "hardware": sorted({x["hardware"] for x in stretches}),
        },
        "metrics": metrics,
        **({ENVELOPE_KEY: None} if whole_floors else {}),
        "latency_torch_fp32_this_host": predictor_latency_ms(model),
        "host": {"machine": platform.machine(), "python": platform.python_version(), "torch": torch.__version__},
    }
    (out_dir / "card.json").write_text(json.dumps(card, indent=1) + "\n")
    return card
