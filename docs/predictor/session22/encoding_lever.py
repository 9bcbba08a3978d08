"""Issue #17's last lever, the observed-cells channel encoding, measured on the host (session 22).

The shipped encoding (:mod:`edge_explorer.predict.encoding`) feeds the U-Net two binary channels, observed FREE and
observed OCCUPIED, with UNKNOWN as (0, 0). This script trains and scores the same U-Net under an alternative
encoding without touching the product: it swaps the encoder that training, validation and the torch predictor call
(``learn.predictor_dataset``, ``learn.unet``) and the network's input width, then runs the project's own commands.

* ``onehot3``: three binary channels, FREE / OCCUPIED / UNKNOWN. Unknown becomes an explicit signal, so the
  convolutions' zero padding at the window's edge no longer reads as "unknown" (``pad_shift`` fills beyond the map
  with UNKNOWN, so only the 51.2 m window's own border differs).
* ``trinary``: one channel, FREE = −1, UNKNOWN = 0, OCCUPIED = +1 (the "ordering" the shipped docstring avoids).

Usage (the encoding first, then the command and its own arguments)::

    python docs/predictor/session22/encoding_lever.py onehot3 train --config lev/onehot3.toml --out lev/onehot3
    python docs/predictor/session22/encoding_lever.py onehot3 f1 collect --split val --plans 100 --noise 0.1 \\
        --levels 0.5 0.8 0.95 0.98 --model lev/onehot3/checkpoint.safetensors --out f1_onehot3.json
    python docs/predictor/session22/encoding_lever.py onehot3 calibrate lev/onehot3/checkpoint.safetensors \\
        --out cal_onehot3.json

``train`` is ``edge-explorer train predictor``; ``f1`` is ``session19/f1_bound.py``; ``calibrate`` is
``session21/calibrate_weights.py``. A checkpoint records its input width, and loading it under the wrong encoding
fails on the first convolution's shape, so results cannot be mixed up silently.
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SCRIPTS = {
    "f1": HERE.parent / "session19" / "f1_bound.py",
    "calibrate": HERE.parent / "session21" / "calibrate_weights.py",
}


def encode_onehot3(windows: np.ndarray) -> np.ndarray:
    """int8 ego windows (H, W) or (N, H, W) → float32 (3, H, W) or (N, 3, H, W): FREE, OCCUPIED, UNKNOWN."""
    from edge_explorer.world.grid import FREE, OCCUPIED, UNKNOWN

    windows = np.asarray(windows)
    axis = windows.ndim - 2
    return np.stack([windows == FREE, windows == OCCUPIED, windows == UNKNOWN], axis=axis).astype(np.float32)


def encode_trinary(windows: np.ndarray) -> np.ndarray:
    """int8 ego windows → float32 (1, H, W) or (N, 1, H, W): FREE −1, UNKNOWN 0, OCCUPIED +1."""
    from edge_explorer.world.grid import FREE, OCCUPIED

    windows = np.asarray(windows)
    value = (windows == OCCUPIED).astype(np.float32) - (windows == FREE).astype(np.float32)
    return np.expand_dims(value, axis=windows.ndim - 2)


ENCODINGS = {"onehot3": (encode_onehot3, 3), "trinary": (encode_trinary, 1)}


def install(name: str) -> None:
    """Route the trainer's, the validator's and the torch predictor's encoder to ``name``, and widen the U-Net."""
    from edge_explorer.learn import predictor_dataset, train_predictor, unet

    encoder, channels = ENCODINGS[name]
    predictor_dataset.encode_windows = encoder
    unet.encode_windows = encoder

    def unet_config(self: train_predictor.PredictorTrainConfig) -> unet.UNetConfig:
        return unet.UNetConfig(in_channels=channels, channels=self.channels, head_channels=self.head_channels)

    train_predictor.PredictorTrainConfig.unet = property(unet_config)


def main() -> None:
    if len(sys.argv) < 3 or sys.argv[1] not in ENCODINGS or sys.argv[2] not in ("train", *SCRIPTS):
        sys.exit(f"usage: {sys.argv[0]} {{{','.join(ENCODINGS)}}} {{train,f1,calibrate}} [arguments of that command]")
    encoding, command, rest = sys.argv[1], sys.argv[2], sys.argv[3:]
    install(encoding)
    if command == "train":
        from edge_explorer.cli import main as cli

        sys.exit(cli(["train", "predictor", *rest]))
    sys.argv = [str(SCRIPTS[command]), *rest]
    runpy.run_path(str(SCRIPTS[command]), run_name="__main__")


if __name__ == "__main__":
    main()
