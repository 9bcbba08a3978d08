"""The export command end to end on tiny networks: formats, gates, cards, bad input."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from edge_explorer.backends.chain import load_model
from edge_explorer.backends.litert_cpu import LiteRtCpuBackend
from edge_explorer.cli import main
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.export import calibration, pipeline, tflite
from edge_explorer.export.networks import predictor_network
from edge_explorer.export.recipe import RecipeError, load_recipe
from edge_explorer.learn.unet import TorchPredictor, load_unet
from edge_explorer.mapping.ego import PREDICTOR_WINDOW_CELLS
from edge_explorer.predict.predictor import PredictorRuntime
from edge_explorer.predict.thresholding import ThresholdConfig
from tests.export.tiny import TINY_TFLITE, TINY_UNET

HAVE_CONVERTER = (tflite.CONVERT_ENV / "bin" / "onnx2tf").is_file()
needs_converter = pytest.mark.skipif(not HAVE_CONVERTER, reason="no .venv-convert (create it with `make convert-env`)")

PREDICTOR_RECIPE = """
model = "predictor"
checkpoint = "ckpt/tiny.safetensors"
[calibration]
plans = 2
held_back_plans = 1
per_plan = 4
[quantization]
method = "minmax"
[formats]
produce = ["onnx_fp32", "onnx_int8"]
[gates]
max_f1_drop = 0.01
min_cell_agreement = 0.99
[latency]
repeats = 2
"""


def write_recipe(root: Path, text: str, name: str = "recipe.toml") -> Path:
    (root / "quantize").mkdir(parents=True, exist_ok=True)
    (root / "ckpt").mkdir(exist_ok=True)
    shutil.copy(TINY_UNET, root / "ckpt" / "tiny.safetensors")
    path = root / "quantize" / name
    path.write_text(text)
    return path


def quiet(_: str) -> None:
    pass


# ---- recipes: every mistake is one line naming itself ------------------------------------------------------------
@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t + "colour = 1\n", "unknown key(s) colour"),
        (lambda t: t.replace('method = "minmax"', 'method = "magic"'), "unknown method 'magic'"),
        (lambda t: t.replace("plans = 2", "plans = 0", 1), "'plans' must be ≥ 1"),
        (lambda t: t.replace("max_f1_drop = 0.01\n", ""), "needs the gate(s) max_f1_drop"),
        (lambda t: t.replace('"onnx_int8"]', '"onnx_int4"]'), "'produce' must be a non-empty list"),
        (lambda t: t.replace('model = "predictor"', 'model = "planner"'), "'model' must be one of"),
        (lambda t: t.replace('model = "predictor"', 'model = "predictor"\nfolder = ".."'), "'folder' must be a plain"),
        (lambda t: t.replace("[calibration]", '[calibration]\nexplorer = "policy"'), "'explorer' for a predictor"),
        (lambda t: t.replace("[quantization]", "[quantization]\nonnx_float_output_conv = 1"), "onnx_float_output_conv"),
    ],
)
def test_a_bad_recipe_is_one_line_naming_the_problem(tmp_path, edit, message):
    path = write_recipe(tmp_path, edit(PREDICTOR_RECIPE))
    with pytest.raises(RecipeError, match=message.replace("(", r"\(").replace(")", r"\)")) as err:
        load_recipe(path)
    assert "\n" not in str(err.value)


def test_the_shipped_recipes_are_valid():
    root = Path(__file__).resolve().parents[2] / "quantize"
    recipes = [load_recipe(p) for p in sorted(root.glob("*.toml"))]
    assert {r.model for r in recipes} == {"predictor", "policy"}
    assert all(r.checkpoint.parent.parent.name == "models" for r in recipes)
    assert all(r.checkpoint.parent.name == r.out_folder for r in recipes)  # each installs beside its checkpoint
    assert {r.out_folder for r in recipes} == {"predictor", "predictor_floors", "policy"}


def test_cli_reports_a_missing_checkpoint_in_one_line_with_exit_2(tmp_path, capsys):
    path = write_recipe(tmp_path, PREDICTOR_RECIPE.replace("ckpt/tiny.safetensors", "ckpt/none.safetensors"))
    assert main(["export", "--recipe", str(path), "--out", str(tmp_path / "models")]) == 2
    err = capsys.readouterr().err.strip()
    assert "ckpt/none.safetensors does not exist" in err and "\n" not in err
    assert not (tmp_path / "models").exists()


def test_a_missing_converter_env_names_the_make_target(tmp_path):
    recipe = load_recipe(write_recipe(tmp_path, PREDICTOR_RECIPE.replace('"onnx_int8"]', '"tflite_int8"]')))
    with pytest.raises(tflite.ConverterError, match="make convert-env") as err:
        pipeline.run_export(recipe, tmp_path / "models", convert_env=tmp_path / "no-env", log=quiet)
    assert "\n" not in str(err.value)


def test_an_empty_calibration_set_is_refused(monkeypatch):
    monkeypatch.setattr("edge_explorer.learn.predictor_data.collect_plan_samples", lambda *a, **k: [])
    config = calibration.CalibrationConfig(plans=1, held_back_plans=1, per_plan=2)
    with pytest.raises(EdgeExplorerError, match="calibration set is empty.*raise \\[calibration\\] plans"):
        calibration.predictor_observations(config, "map")


# ---- round trips ---------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def predictor_export(tmp_path_factory) -> pipeline.ExportReport:
    root = tmp_path_factory.mktemp("export")
    (root / "models" / "predictor").mkdir(parents=True)
    (root / "models" / "predictor" / "card.json").write_text(json.dumps({"model": "tiny", "training": {"x": 1}}))
    return pipeline.run_export(load_recipe(write_recipe(root, PREDICTOR_RECIPE)), root / "models", log=quiet)


@pytest.mark.slow
def test_predictor_round_trip_installs_formats_that_load_and_match_torch(predictor_export):
    report = predictor_export
    assert report.passed, report.table()
    card = json.loads((report.out_dir / "card.json").read_text())
    assert card["training"] == {"x": 1} and card["model"] == "tiny"  # the trainer's keys are kept
    assert set(card["artifacts"]) == {"predictor_fp32.onnx", "predictor_int8.onnx"}
    params = sum(p.numel() for p in load_unet(TINY_UNET).parameters())  # onnx-tool also counts Resize's scale constants
    assert params <= card["export"]["graph"]["params"] <= params + 8
    assert card["export"]["graph"]["macs"] > 0
    torch_predictor = TorchPredictor(load_unet(TINY_UNET))
    window = np.zeros((PREDICTOR_WINDOW_CELLS, PREDICTOR_WINDOW_CELLS), np.int8)
    window[100:160, 120] = 1
    window[100:160, 121:140] = -1
    expected = torch_predictor(window)
    for precision, tolerance in (("fp32", 1e-4), ("int8", 0.1)):
        runtime = PredictorRuntime(load_model(report.out_dir, ("onnxruntime-cpu",), precision=precision))
        assert runtime.model.artifact.name == f"predictor_{precision}.onnx"
        assert np.abs(runtime(window) - expected).mean() < tolerance / 4
        assert np.abs(runtime(window) - expected).max() < tolerance * 4
    assert "F1" in report.table() and "ONNX int8 (QDQ)" in report.table()


@pytest.mark.slow
def test_calibrating_on_all_unknown_maps_fails_the_gate_and_installs_nothing(tmp_path, monkeypatch):
    real = pipeline.collect_observations

    def all_unknown(recipe, network):
        obs = real(recipe, network)
        return replace(obs, calibration=[{k: np.zeros_like(v) for k, v in f.items()} for f in obs.calibration])

    monkeypatch.setattr(pipeline, "collect_observations", all_unknown)
    out = tmp_path / "models"
    (out / "predictor").mkdir(parents=True)
    (out / "predictor" / "card.json").write_text('{"previous": true}')
    report = pipeline.run_export(load_recipe(write_recipe(tmp_path, PREDICTOR_RECIPE)), out, log=quiet)
    assert not report.passed
    assert [f.split(":")[0] for f in report.failures()] == ["onnx_int8"]  # fp32 is fine, int8 is not
    int8 = next(r for r in report.rows if r.format == "onnx_int8")
    assert int8.details["qdq_error_report"] and "xmodel_sqnr_db" in int8.details["qdq_error_report"][0]
    assert sorted(p.name for p in (out / "predictor").iterdir()) == ["card.json"]
    assert (out / "predictor" / "card.json").read_text() == '{"previous": true}'
    assert [p.name for p in out.iterdir()] == ["predictor"]  # the temporary folder is gone


# ---- TFLite ------------------------------------------------------------------------------------------------------
def test_the_committed_int8_tflite_runs_under_litert_with_xnnpack_and_matches_torch():
    backend = LiteRtCpuBackend(1)
    backend.load(TINY_TFLITE)
    assert [(s.name, s.shape, s.dtype) for s in backend.inputs] == [("map", (1, 256, 256, 2), "int8")]
    assert [(s.name, s.dtype) for s in backend.outputs] == [("occupancy", "int8")]
    coverage = tflite.xnnpack_coverage(TINY_TFLITE)
    assert coverage["delegated_nodes"] > 0 and coverage["partitions"] >= 1
    assert tflite.read_metadata(TINY_TFLITE)["edge_explorer.model"] == "predictor"
    model = type("Loaded", (), {"name": "tiny", "backend": backend, "run": lambda self, x: backend.run(x)})()
    runtime = PredictorRuntime(model, ThresholdConfig())  # NHWC input: the runtime transposes the encoded window
    assert runtime.channels_last and runtime.window_cells == PREDICTOR_WINDOW_CELLS
    window = np.zeros((PREDICTOR_WINDOW_CELLS, PREDICTOR_WINDOW_CELLS), np.int8)
    window[90:170, 128] = 1
    window[90:170, 129:150] = -1
    expected = TorchPredictor(load_unet(TINY_UNET))(window)
    assert np.abs(runtime(window) - expected).mean() < 0.02


def test_the_edgetpu_report_names_every_op_and_says_the_compiler_is_missing(tmp_path):
    report = tflite.edgetpu_report(TINY_TFLITE, tmp_path)
    assert report["ops"]["CONV_2D"] > 0 and report["unsupported_ops"] == {}
    assert report["tensor_problems"] == [] and report["cpu_fallback"].startswith("none")
    if shutil.which("edgetpu_compiler") is None:
        assert "not installed" in report["compiler"]


@needs_converter
@pytest.mark.slow
def test_onnx2tf_conversion_of_a_tiny_predictor_passes_its_gates(tmp_path):
    text = PREDICTOR_RECIPE.replace('"onnx_int8"]', '"tflite_int8"]')
    report = pipeline.run_export(load_recipe(write_recipe(tmp_path, text)), tmp_path / "models", log=quiet)
    assert report.passed, report.table()
    row = next(r for r in report.rows if r.format == "tflite_int8")
    assert row.details["xnnpack"]["delegated_nodes"] > 0
    runtime = PredictorRuntime(load_model(report.out_dir, ("litert-cpu",)))
    assert runtime.model.artifact.name == "predictor_int8.tflite" and runtime.channels_last
    fp32 = load_model(report.out_dir, ("onnxruntime-cpu",), precision="fp32")  # the converter left it as carded
    assert fp32.artifact.name == "predictor_fp32.onnx" and "skipped" not in fp32.report


def test_predictor_network_declares_the_runtime_contract():
    network = predictor_network(load_unet(TINY_UNET))
    assert network.inputs == {"map": (1, 2, 256, 256)} and network.outputs == ("occupancy",)
    assert {"edge_explorer.git_revision", "edge_explorer.thresholds"} <= set(network.metadata)
