"""The (goal) policy's export: its network view, the masked goal gate, and round trips on a tiny GoalNet flown on the
two-room plan (the val split is replaced by it, so the rollouts take seconds)."""

from __future__ import annotations

import shutil
from argparse import Namespace
from collections import Counter
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from edge_explorer.commands import export as cli
from edge_explorer.errors import EdgeExplorerError
from edge_explorer.export import calibration, gates, pipeline
from edge_explorer.export.networks import policy_network
from edge_explorer.export.onnx_formats import export_fp32, quantize_int8
from edge_explorer.export.recipe import load_recipe
from edge_explorer.learn.goal_net import GoalNet, GoalNetConfig
from edge_explorer.plan.goal_grid import GOAL_GRID_CELLS
from edge_explorer.world.catalog import plan_to_raster
from tests.conftest import two_room_plan
from tests.export.test_export import HAVE_CONVERTER, quiet

G = GOAL_GRID_CELLS
# What torch.onnx (dynamo, opset 18) emits for the GoalNet: the ReLU code encoding (Sub, Relu, Mul, Unsqueeze +
# Concat for its stack), zero Pad, MaxPool, strided Conv + Relu, the last-motion bias (Gemm + Unsqueeze + Add),
# nearest Resize, Concat skips, and the channel select + crop of the scores (torch's Gather, rewritten as Slice +
# Squeeze by onnx_formats.gather_to_slice; Slice). All of them have int8 QDQ kernels or are exact on int8, and
# onnx2tf maps them onto Edge TPU operations.
# The exported scores' window (networks.WindowedScores) adds ReduceMax (the per-decision best logit) and Clip(0, 6)
# (ReLU6, fused into its convolution).
GOAL_ONNX_OPS = {"Conv", "Relu", "MaxPool", "Pad", "Resize", "Concat", "Add", "Sub", "Mul", "Unsqueeze", "Gemm",
                 "Slice", "Squeeze", "ReduceMax", "Clip"}  # fmt: skip
GOAL_RECIPE = """
model = "policy"
checkpoint = "ckpt/policy.safetensors"
[calibration]
plans = 2
held_back_plans = 2
per_plan = 8
explorer = "policy"
[formats]
produce = ["onnx_fp32", "onnx_int8"]
[gates]
min_top1_agreement = 0.98
[latency]
repeats = 2
"""


def tiny_goal_net(seed: int = 0) -> GoalNet:
    torch.manual_seed(seed)
    return GoalNet(GoalNetConfig(encoder=(4, 4, 4, 4), decoder=(4, 4))).eval()


@pytest.fixture
def two_rooms_as_val(monkeypatch) -> None:
    """Every val plan of the rollouts is the two-room plan (each episode still has its own seed)."""
    raster = plan_to_raster(two_room_plan())
    monkeypatch.setattr(calibration, "val_rasters", lambda c: ([raster] * c.plans, [raster] * c.held_back_plans))


def goal_recipe(root: Path, text: str = GOAL_RECIPE) -> Path:
    (root / "quantize").mkdir(parents=True, exist_ok=True)
    path = root / "quantize" / "policy.toml"
    path.write_text(text)
    return path


def random_observation(seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "high": rng.integers(-1, 3, (1, 237, 237)).astype(np.float32),
        "thres": rng.integers(-1, 3, (1, 237, 237)).astype(np.float32),
        "last_action": np.eye(6, dtype=np.float32)[[seed % 6]],
    }


# ---- the gate ----------------------------------------------------------------------------------------------------
def test_the_goal_gate_counts_only_the_valid_cells():
    mask = np.zeros((G, G), bool)
    mask[10, 10] = mask[20, 30] = True
    ref = np.zeros((G, G), np.float32)
    ref[10, 10], ref[20, 30] = 2.0, 1.0
    invalid_differs = ref.copy()
    invalid_differs[0, 0] = 9.0  # the unmasked argmax moves to a masked cell: no goal changes
    valid_differs = ref.copy()
    valid_differs[20, 30] = 3.0  # the best valid goal changes
    result = gates.goal_gate([ref, ref], [invalid_differs, ref], [mask, mask], {"min_top1_agreement": 0.98})
    assert result.passed and result.figures["top1_agreement"] == 1.0
    assert result.figures["unmasked_top1_agreement"] == 0.5 and result.figures["mean_valid_cells"] == 2.0
    result = gates.goal_gate([ref, ref], [valid_differs, ref], [mask, mask], {"min_top1_agreement": 0.98})
    assert not result.passed and result.figures["top1_agreement"] == 0.5
    assert "masked top-1 goal agreement 0.5000 < 0.98" in result.failures[0]
    assert gates.masked_argmax(invalid_differs, mask) == 10 * G + 10


# ---- the network view ----------------------------------------------------------------------------------------------
def test_the_goal_policy_onnx_has_only_the_logits_edge_tpu_ops_and_matches_torch(tmp_path):
    network = policy_network(tiny_goal_net())
    assert network.inputs == {"high": (1, 237, 237), "thres": (1, 237, 237), "last_action": (1, 6)}
    assert network.outputs == ("logits",)
    assert {"edge_explorer.goal_grid", "edge_explorer.input_encoding"} <= set(network.metadata)
    path = tmp_path / "goal_fp32.onnx"
    export_fp32(network, path)
    model = onnx.load(path)
    ops = Counter(n.op_type for n in model.graph.node)
    assert set(ops) <= GOAL_ONNX_OPS, f"unexpected ops {set(ops) - GOAL_ONNX_OPS}"
    assert "ReduceMean" not in ops  # the value head (training only) is not in the graph
    assert all(a.s == b"nearest" for n in model.graph.node if n.op_type == "Resize" for a in n.attribute
               if a.name == "mode")  # fmt: skip
    assert [o.name for o in model.graph.output] == ["logits"]
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    for seed in (0, 1):
        feed = random_observation(seed)
        with torch.no_grad():
            expected = network.module(*(torch.from_numpy(feed[n]) for n in network.inputs)).numpy()
        (got,) = session.run(None, feed)
        assert got.shape == (1, G, G)
        np.testing.assert_allclose(got, expected, atol=1e-4)


# ---- round trips ---------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_goal_policy_int8_onnx_gate_reports_the_masked_agreement_it_measures(tmp_path, two_rooms_as_val):
    net = tiny_goal_net()
    recipe = load_recipe(goal_recipe(tmp_path))
    report = pipeline.run_export(recipe, tmp_path / "models", network=policy_network(net), log=quiet)
    fp32, int8 = (next(r for r in report.rows if r.format == f) for f in ("onnx_fp32", "onnx_int8"))
    assert fp32.passed  # parity with torch
    figures = int8.gate.figures
    assert figures["observations"] > 4 and figures["mean_valid_cells"] >= 1
    assert int8.passed == (figures["top1_agreement"] >= 0.98)
    card = report.card["export"]
    assert card["calibration"]["held_back_observations"] == figures["observations"]
    assert card["metadata"]["edge_explorer.model"] == "policy" and card["graph"]["macs"] > 0
    assert fp32.details["decision_parity_vs_unwrapped_net"] == 1.0
    # the same figure, recomputed outside the pipeline from the same decisions and calibration, against the
    # unwrapped net's own logits
    network = policy_network(net)
    obs = pipeline.collect_observations(recipe, network)
    network = network.prepare([network.cast(f) for f in obs.calibration])
    export_fp32(network, tmp_path / "fp32.onnx")
    quantize_int8(tmp_path / "fp32.onnx", tmp_path / "int8.onnx", obs.calibration, recipe.quantization)
    session = ort.InferenceSession(str(tmp_path / "int8.onnx"), providers=["CPUExecutionProvider"])
    with torch.no_grad():
        reference = [net(*(torch.from_numpy(f[n]) for n in network.inputs))[0].numpy() for f in obs.held_back]
    same = [
        gates.masked_argmax(session.run(None, feed)[0], m) == gates.masked_argmax(r, m)
        for feed, r, m in zip(obs.held_back, reference, obs.masks, strict=True)
    ]
    assert np.mean(same) == figures["top1_agreement"] and len(same) == figures["observations"]


@pytest.mark.slow
def test_goal_observations_record_valid_masks_and_act_only_on_valid_cells(two_rooms_as_val):
    chosen: list[bool] = []

    def act(obs: dict[str, np.ndarray], mask: np.ndarray) -> int:
        cell = int(np.flatnonzero(mask)[0])
        chosen.append(bool(mask[cell]))
        return cell

    config = calibration.CalibrationConfig(plans=1, held_back_plans=1, per_plan=5, explorer="policy")
    obs = calibration.goal_observations(config, act, None)
    assert 0 < len(obs.held_back) <= 5 and len(obs.masks) == len(obs.held_back)
    assert all(m.shape == (G, G) and m.any() for m in obs.masks)
    assert all(chosen) and obs.held_back[0]["high"].shape == (1, 237, 237)
    assert obs.held_back[0]["high"].dtype == np.float32


@pytest.mark.skipif(not HAVE_CONVERTER, reason="no .venv-convert (create it with `make convert-env`)")
@pytest.mark.slow
def test_the_goal_policy_tflite_is_full_integer_and_edge_tpu_clean(tmp_path, two_rooms_as_val):
    text = GOAL_RECIPE.replace('"onnx_int8"]', '"tflite_int8"]')
    net = tiny_goal_net()
    report = pipeline.run_export(load_recipe(goal_recipe(tmp_path, text)), tmp_path / "models",
                                 network=policy_network(net), log=quiet)  # fmt: skip
    row = next(r for r in report.rows if r.format == "tflite_int8")
    assert row.details["edgetpu"]["unsupported_ops"] == {}, row.details["edgetpu"]
    assert row.details["xnnpack"]["delegated_nodes"] > 0
    inputs = sorted((s.name, s.dtype) for s in row.card.inputs)  # fed by name, in the converter's order
    assert inputs == [("high", "int8"), ("last_action", "int8"), ("thres", "int8")]
    assert [(s.name, tuple(s.shape)) for s in row.card.outputs] == [("logits", (1, G, G))]
    assert row.passed == (row.gate.figures["top1_agreement"] >= 0.98)


# ---- recipes -----------------------------------------------------------------------------------------------------
def test_export_all_skips_a_recipe_whose_checkpoint_is_not_trained_yet(tmp_path, monkeypatch, capsys):
    goal_recipe(tmp_path)
    monkeypatch.setattr(cli, "RECIPE_DIR", tmp_path / "quantize")
    with pytest.raises(EdgeExplorerError, match="no recipe .* has its checkpoint"):
        cli.export_cli(Namespace(all=True, recipe=None, out=tmp_path / "models", json=None))
    out = capsys.readouterr().out
    assert "== policy: skipped, checkpoint" in out and "policy.safetensors does not exist" in out

    shutil.copy(Path(__file__).parent / "data" / "tiny_unet.safetensors", tmp_path / "predictor.safetensors")
    (tmp_path / "quantize" / "predictor.toml").write_text(
        'model = "predictor"\ncheckpoint = "predictor.safetensors"\n[gates]\nmax_f1_drop = 0.01\n'
        "min_cell_agreement = 0.99\n"
    )
    ran: list[str] = []

    def fake_run_export(recipe, out):
        ran.append(recipe.name)
        return type("Report", (), {"passed": True, "out_dir": out, "table": lambda s: "", "to_json": lambda s: {}})()

    monkeypatch.setattr(pipeline, "run_export", fake_run_export)
    assert cli.export_cli(Namespace(all=True, recipe=None, out=tmp_path / "models", json=None)) == 0
    assert ran == ["predictor"] and "policy: skipped" in capsys.readouterr().out


# ---- the int8-friendly export transforms (networks.WindowedScores, networks.equalize_goal_net) ----------------------
def _batch(seeds) -> tuple[torch.Tensor, ...]:
    feeds = [random_observation(s) for s in seeds]
    return tuple(torch.from_numpy(np.concatenate([f[n] for f in feeds])) for n in ("high", "thres", "last_action"))


def test_windowed_scores_rise_strictly_with_the_logits_so_every_masked_argmax_is_the_nets():
    net = tiny_goal_net(1)
    with torch.no_grad():  # spread the logits over ~30 like a trained net's, so the tail and the window both matter
        net.score.weight.mul_(40.0)
    network = policy_network(net, equalization=None)
    rng = np.random.default_rng(0)
    with torch.no_grad():
        for seed in range(3):
            inputs = _batch([seed])
            logits = network.decision_reference(*inputs)[0].numpy()
            scores = network.module(*inputs)[0].numpy()
            assert scores.shape == logits.shape == (G, G)
            order = np.argsort(logits, axis=None)
            within = logits.flat[order] > logits.max() - (8.0 + 32.0)  # above the flat end of the tail
            rise, step = np.diff(scores.flat[order][within]), np.diff(logits.flat[order][within])
            assert np.all(rise >= -1e-5) and np.all(rise[step > 1e-3] > 0), "scores must rise with the logits"
            for _ in range(20):
                mask = rng.random((G, G)) < 0.05
                mask[rng.integers(G), rng.integers(G)] = True
                assert gates.masked_argmax(scores, mask) == gates.masked_argmax(logits, mask)


def test_the_window_keeps_headroom_above_the_best_cell_for_int8():
    """The best cell scores below the ceiling column (cropped away) so its int8 value is never clipped."""
    from edge_explorer.export.networks import ScoreWindow, WindowedScores

    net = tiny_goal_net(2)
    window = ScoreWindow()
    head = WindowedScores(net.score, G, window.window, window.margin, window.tail, window.tail_weight)
    with torch.no_grad():
        out = head(torch.rand(1, net.score.in_channels, G + 1, G + 1) * 5)
    assert out.shape == (1, 1, G + 1, G + 1)
    ceiling = 6.0 * (1.0 + window.tail_weight)
    np.testing.assert_allclose(out[0, 0, :, G].numpy(), ceiling, rtol=1e-6)
    assert out[0, 0, :G, :G].max() < ceiling - 0.1


def test_equalization_keeps_the_logits_and_evens_the_channel_ranges():
    from edge_explorer.export.networks import equalize_goal_net

    torch.manual_seed(3)
    net = GoalNet(GoalNetConfig(encoder=(4, 6, 6, 8), decoder=(6, 4))).eval()
    with torch.no_grad():  # uneven channels, as training leaves them
        net.up2[0].weight[:2] *= 20.0
        net.up2[0].bias[:2] *= 20.0
    feeds = [random_observation(s) for s in range(4)]
    before = net.up2[0].weight.detach().clone()
    equalized = equalize_goal_net(net, feeds, strength=1.0)
    inputs = _batch(range(4, 7))
    with torch.no_grad():
        (a, va), (b, vb) = net(*inputs), equalized(*inputs)
        np.testing.assert_allclose(b.numpy(), a.numpy(), rtol=1e-4, atol=1e-4 * float(a.abs().max()))
        np.testing.assert_allclose(vb.numpy(), va.numpy(), rtol=1e-4, atol=1e-4)

        def spread(model: GoalNet) -> float:
            ranges = []
            model.up2.register_forward_hook(lambda _m, _i, o: ranges.append(o.amax(dim=(0, 2, 3))))
            model(*_batch(range(3)))
            r = ranges[-1][ranges[-1] > 0]
            return float(r.max() / r.min())

        assert spread(equalized) < spread(net)
    assert torch.equal(net.up2[0].weight, before)  # the original is untouched (a copy is equalized)
