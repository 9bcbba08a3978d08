import re
import tomllib

import pytest

from edge_explorer.profiling.device_profile import (
    PROFILES_DIR,
    ProfileError,
    list_profiles,
    load_profile,
    parse_profile,
)

REQUIRED = {"host", "nuc10-i7-10710u", "coral-usb", "voxl-snapdragon821"}


def test_shipped_profiles_load():
    assert REQUIRED <= set(list_profiles())
    for name in list_profiles():
        profile = load_profile(name)
        assert profile.name == name
        assert profile.rates_hz.setpoint >= 10.0  # PX4 offboard needs > 2 Hz; DESIGN.md §8 asks ≥ 10 Hz
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
    assert coral.cpu_speed_ratio_fp32(host) == pytest.approx(83.0 / 12.0)
    assert host.cpu_speed_ratio_fp32(host) == 1.0


def test_unknown_profile_lists_known(tmp_path):
    with pytest.raises(ProfileError, match="not found .*host"):
        load_profile("mars-rover")
    bad = tmp_path / "x.toml"
    bad.write_text("name = ")
    with pytest.raises(ProfileError, match="not valid TOML"):
        load_profile(bad)
