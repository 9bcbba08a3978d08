"""Inference backends for the daemon's models, behind one interface (:class:`.base.InferenceBackend`).

* ``edgetpu`` — LiteRT with the Edge TPU delegate (``libedgetpu.so.1``) on an ``*_edgetpu.tflite`` artifact;
* ``litert-cpu`` — LiteRT (ai-edge-litert) on the CPU with XNNPACK, int8 or float ``.tflite``;
* ``onnxruntime-cpu`` — onnxruntime's CPU execution provider, ``.onnx`` (float or QDQ int8).

:func:`edge_explorer.backends.chain.load_model` tries them in a device profile's order, after checking each
artifact against its model card (:mod:`edge_explorer.backends.card`). Callers always pass and receive float32.
"""
