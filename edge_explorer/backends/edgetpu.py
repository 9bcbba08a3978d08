"""The Edge TPU (Coral) through LiteRT's external delegate ``libedgetpu.so.1``.

Runs only artifacts compiled by ``edgetpu_compiler`` (``*_edgetpu.tflite``): their Edge TPU ops are a custom op
the delegate executes; anything the compiler left on the CPU runs in LiteRT as usual. Input quantization and
output dequantization are the LiteRT backend's.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

from ai_edge_litert.interpreter import Interpreter, load_delegate

from edge_explorer.backends.base import BackendUnavailable
from edge_explorer.backends.litert_cpu import LiteRtCpuBackend

EDGETPU_LIBRARY = "libedgetpu.so.1"
EDGETPU_SUFFIX = "_edgetpu.tflite"


class EdgeTpuBackend(LiteRtCpuBackend):
    """``edgetpu``: LiteRT with the Edge TPU delegate."""

    name = "edgetpu"
    artifact_format = "edgetpu_tflite"

    def _make_interpreter(self, path: Path) -> Interpreter:
        if not path.name.endswith(EDGETPU_SUFFIX):
            raise BackendUnavailable(
                f"{path.name} is not compiled for the Edge TPU (expected *{EDGETPU_SUFFIX} from edgetpu_compiler)"
            )
        try:
            # Probe the library first: LiteRT's load_delegate leaves a half-built object behind when it is missing.
            ctypes.CDLL(EDGETPU_LIBRARY)
            delegate = load_delegate(EDGETPU_LIBRARY)
        except (ValueError, OSError) as exc:
            first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise BackendUnavailable(
                f"no Edge TPU present: {EDGETPU_LIBRARY} could not be loaded ({first_line})"
            ) from exc
        return Interpreter(model_path=str(path), experimental_delegates=[delegate], num_threads=self.num_threads)
