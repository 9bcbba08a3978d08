import re
import tomllib

import pytest

from edge_explorer.runtime.daemon import choose_models
from edge_explorer.runtime.device_profile import (
    PROFILES_DIR,
    ProfileError,
    list_profiles,
    load_profile,
    parse_profile,
)
from tests.predict.test_predictor import write_predictor_model

REQUIRED = {"host", "nuc10-i7-10710u", "coral-usb", "voxl-snapdragon821"}


def test_shipped_profiles_load():
    assert REQUIRED <= set(list_profiles())
    for name in list_profiles():
        profile = load_profile(name)
        assert profile.name == name
        assert profile.rates_hz.setpoint >= 10.0  # PX4 offboard needs > 2 Hz; docs/design.md §8 asks ≥ 10 Hz
    assert load_profile("host").measured and not load_profile("coral-usb").measured
    assert load_profile("coral-usb").accelerator.kind == "edgetpu"
    # the paper's reference budgets
    assert load_profile("nuc10-i7-10710u").budgets_ms.predictor == 135.0
    assert load_profile("coral-usb").budgets_ms.predictor == 150.0


def _host() -> dict:
    return tomllib.loads((PROFILES_DIR / "host.toml").read_text())


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda d: d.pop("cpu"), "missing table [cpu]"),
        (lambda d: d["cpu"].update(turbo=True), "unknown key(s) ['turbo'] in [cpu]"),
        (lambda d: d["budgets_ms"].pop("policy"), "missing key(s) ['policy']"),
        (lambda d: d["rates_hz"].update(depth=-1), "non-negative number"),
        (lambda d: d["accelerator"].update(kind="gpu"), "kind must be one of"),
        (lambda d: d["backends"].update(order=["tensorrt"]), "order must be a non-empty list"),
        (lambda d: d.update(measured="yes"), "'measured' must be true"),
    ],
)
def test_bad_profiles_name_the_problem(mutate, message):
    data = _host()
    mutate(data)
    with pytest.raises(ProfileError, match=re.escape(message)):
        parse_profile(data, "bad.toml")


def test_a_target_cannot_put_an_edge_tpu_it_lacks_first():
    data = tomllib.loads((PROFILES_DIR / "nuc10-i7-10710u.toml").read_text())
    data["backends"]["order"] = ["edgetpu", "onnxruntime-cpu"]
    with pytest.raises(ProfileError, match=re.escape("backend 'edgetpu' comes first but [accelerator] kind")):
        parse_profile(data, "nuc.toml")
    data["budgets_ms"]["fuse"] = 0.0
    with pytest.raises(ProfileError, match="every rate and stage budget must be positive"):
        parse_profile(data, "nuc.toml")


def test_peak_ratios_are_host_over_target():
    host, coral = load_profile("host"), load_profile("coral-usb")
    assert coral.cpu_speed_ratio_fp32(host) == pytest.approx(host.cpu.peak_fp32_gflops_per_core / 12.0)
    assert host.cpu_speed_ratio_fp32(host) == 1.0


def test_unknown_profile_lists_known(tmp_path):
    with pytest.raises(ProfileError, match="not found .*host"):
        load_profile("mars-rover")
    bad = tmp_path / "x.toml"
    bad.write_text("name = ")
    with pytest.raises(ProfileError, match="not valid TOML"):
        load_profile(bad)


def test_a_model_may_have_its_own_backend_order():
    host = load_profile("host")
    assert host.order_for("policy") == ("litert-cpu", "onnxruntime-cpu")  # measured faster here (host.toml)
    assert host.order_for("predictor") == host.backend_order
    nuc = load_profile("nuc10-i7-10710u")
    assert nuc.model_orders == {} and nuc.order_for("policy") == nuc.backend_order
    only_litert = host.restricted_to(("litert-cpu",))
    assert only_litert.order_for("policy") == ("litert-cpu",) and only_litert.backend_order == ("litert-cpu",)


@pytest.mark.parametrize(
    ("backends", "message"),
    [
        ({"order": ["litert-cpu"], "planner": ["litert-cpu"]}, "unknown key(s) ['planner'] in [backends]"),
        ({"order": ["litert-cpu"], "policy": []}, "[backends] policy must be a non-empty list"),
        ({"order": ["litert-cpu"], "policy": ["tensorrt"]}, "[backends] policy must be a non-empty list"),
        ({"order": ["litert-cpu"], "policy": ["litert-cpu", "litert-cpu"]}, "[backends] policy names a backend twice"),
        ({"policy": ["litert-cpu"]}, "[backends] needs order = [...]"),
        ({"order": ["litert-cpu"], "predictor": ["edgetpu", "litert-cpu"]}, "predictor: backend 'edgetpu' comes first"),
    ],
)
def test_bad_backend_orders_name_the_problem(backends, message):
    data = tomllib.loads((PROFILES_DIR / "nuc10-i7-10710u.toml").read_text())
    data["backends"] = backends
    with pytest.raises(ProfileError, match=re.escape(message)):
        parse_profile(data, "nuc.toml")


def test_the_daemon_loads_each_model_in_its_own_order(tmp_path):
    """The per-model order reaches the daemon's model loading: the tiny predictor has only an ONNX artifact, so an
    order of LiteRT alone cannot load it while the default order does."""
    write_predictor_model(tmp_path / "predictor")
    default = choose_models(tmp_path, "frontier", ("litert-cpu", "onnxruntime-cpu"))
    assert default.predictor is not None and default.predictor.model.backend.name == "onnxruntime-cpu"
    own = choose_models(
        tmp_path, "frontier", ("litert-cpu", "onnxruntime-cpu"), model_orders={"predictor": ("litert-cpu",)}
    )
    assert own.predictor is None and "litert-cpu skipped: no tflite artifact" in own.notes[-1]
