"""Device profiles (``profiles/*.toml``, docs/design.md §9): what a target board can do and what each stage may cost.

A profile names the CPU (cores, peak fp32 / int8 throughput per core), the accelerator (``none`` or ``edgetpu``
with its peak int8 TOPS), memory, the latency budget per stage, the rates, CPU and memory ceilings, and the
order in which the daemon tries inference backends: ``[backends] order`` for every model, and optionally
``predictor = [...]`` / ``policy = [...]`` for one model (the fastest backend differs per network on some CPUs:
on the host the int8 TFLite predictor is faster than the int8 ONNX one, the int8 ONNX policy faster than the
int8 TFLite one). It is read by the daemon (backend order, rates) and by the
profiling report (budgets, and the peak-throughput ratio used to estimate a target from host measurements).
Import-light on purpose: the daemon loads it.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from edge_explorer.errors import EdgeExplorerError

PROFILES_DIR = Path(__file__).resolve().parents[2] / "profiles"
BACKEND_NAMES: tuple[str, ...] = ("edgetpu", "litert-cpu", "onnxruntime-cpu")
ACCELERATORS: tuple[str, ...] = ("none", "edgetpu")
MODEL_NAMES: tuple[str, ...] = ("predictor", "policy")  # the networks a [backends] table may order on their own


class ProfileError(EdgeExplorerError, ValueError):
    """A device profile is missing, malformed or inconsistent."""


@dataclass(frozen=True)
class CpuSpec:
    model: str
    cores: int
    clock_ghz: float
    peak_fp32_gflops_per_core: float
    peak_int8_gops_per_core: float


@dataclass(frozen=True)
class AcceleratorSpec:
    kind: str
    peak_int8_tops: float


@dataclass(frozen=True)
class MemorySpec:
    total_mb: float
    rss_ceiling_mb: float


@dataclass(frozen=True)
class StageBudgetsMs:
    fuse: float
    predictor: float
    policy: float
    decision: float


@dataclass(frozen=True)
class RatesHz:
    depth: float
    decision: float
    setpoint: float


@dataclass(frozen=True)
class Ceilings:
    cpu_percent_of_one_core: float


@dataclass(frozen=True)
class DeviceProfile:
    name: str
    description: str
    measured: bool  # True only for the machine the measurements come from
    cpu: CpuSpec
    accelerator: AcceleratorSpec
    memory: MemorySpec
    budgets_ms: StageBudgetsMs
    rates_hz: RatesHz
    ceilings: Ceilings
    backend_order: tuple[str, ...]  # every model's, unless model_orders names it
    source: str = ""
    model_orders: dict[str, tuple[str, ...]] = field(default_factory=dict)  # model name → its own backend order

    def order_for(self, model: str) -> tuple[str, ...]:
        """The backends the daemon tries for ``model`` (``predictor`` or ``policy``), in order."""
        return self.model_orders.get(model, self.backend_order)

    def restricted_to(self, backends: tuple[str, ...]) -> DeviceProfile:
        """This profile with every backend order cut down to ``backends`` (``profile --backend``); an order may
        become empty, and then no backend of it can run the model."""
        keep = lambda order: tuple(b for b in order if b in backends)  # noqa: E731
        orders = {model: keep(order) for model, order in self.model_orders.items()}
        return replace(self, backend_order=keep(self.backend_order), model_orders=orders)

    def cpu_speed_ratio_fp32(self, reference: DeviceProfile) -> float:
        """Single-core peak fp32 throughput of ``reference`` over this device's: > 1 means this device is slower.
        The factor the profiling report scales the reference's measured non-network stages by."""
        return reference.cpu.peak_fp32_gflops_per_core / self.cpu.peak_fp32_gflops_per_core


_SECTIONS: dict[str, type] = {
    "cpu": CpuSpec,
    "accelerator": AcceleratorSpec,
    "memory": MemorySpec,
    "budgets_ms": StageBudgetsMs,
    "rates_hz": RatesHz,
    "ceilings": Ceilings,
}


def _section(data: dict[str, Any], key: str, cls: type, src: str) -> Any:
    table = data.get(key)
    if not isinstance(table, dict):
        raise ProfileError(f"{src}: missing table [{key}]")
    names = {f.name: f.type for f in fields(cls)}
    unknown = sorted(set(table) - set(names))
    missing = sorted(set(names) - set(table))
    if unknown:
        raise ProfileError(f"{src}: unknown key(s) {unknown} in [{key}]; allowed: {sorted(names)}")
    if missing:
        raise ProfileError(f"{src}: missing key(s) {missing} in [{key}]")
    values = {}
    for name, type_name in names.items():
        value = table[name]
        if type_name == "str":
            if not isinstance(value, str):
                raise ProfileError(f"{src}: [{key}] {name} must be a string, got {value!r}")
        else:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0:
                raise ProfileError(f"{src}: [{key}] {name} must be a non-negative number, got {value!r}")
            if type_name == "int" and int(value) != value:
                raise ProfileError(f"{src}: [{key}] {name} must be an integer, got {value!r}")
        values[name] = value
    return cls(**values)


def parse_profile(data: dict[str, Any], source: str) -> DeviceProfile:
    """Validate a parsed TOML document; every error names the file, the key and the fix."""
    allowed = {"name", "description", "measured", "backends", *_SECTIONS}
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise ProfileError(f"{source}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    for key in ("name", "description"):
        if not isinstance(data.get(key), str) or not data[key]:
            raise ProfileError(f"{source}: {key!r} must be a non-empty string")
    if not isinstance(data.get("measured"), bool):
        raise ProfileError(f"{source}: 'measured' must be true (this host) or false (an estimated target)")
    parts = {key: _section(data, key, cls, source) for key, cls in _SECTIONS.items()}
    if parts["accelerator"].kind not in ACCELERATORS:
        raise ProfileError(
            f"{source}: [accelerator] kind must be one of {ACCELERATORS}, got {parts['accelerator'].kind!r}"
        )
    if (
        parts["cpu"].cores < 1
        or parts["cpu"].peak_fp32_gflops_per_core <= 0
        or parts["cpu"].peak_int8_gops_per_core <= 0
    ):
        raise ProfileError(f"{source}: [cpu] needs cores ≥ 1 and positive peak throughputs")
    if min(vars(parts["rates_hz"]).values()) <= 0 or min(vars(parts["budgets_ms"]).values()) <= 0:
        raise ProfileError(f"{source}: every rate and stage budget must be positive")
    backends = data.get("backends")
    if not isinstance(backends, dict):
        raise ProfileError(f"{source}: missing table [backends] (order = [...], drawn from {list(BACKEND_NAMES)})")
    unknown = sorted(set(backends) - {"order", *MODEL_NAMES})
    if unknown:
        raise ProfileError(
            f"{source}: unknown key(s) {unknown} in [backends]; allowed: 'order' and a per-model order for "
            f"{list(MODEL_NAMES)}"
        )
    orders = {
        key: _backend_order(backends, key, parts["accelerator"].kind, data["measured"], source) for key in backends
    }
    if "order" not in orders:
        raise ProfileError(f"{source}: [backends] needs order = [...] (the default for every model)")
    return DeviceProfile(
        name=data["name"],
        description=data["description"],
        measured=data["measured"],
        backend_order=orders.pop("order"),
        source=source,
        model_orders=orders,
        **parts,
    )


def _backend_order(backends: dict[str, Any], key: str, accelerator: str, measured: bool, src: str) -> tuple[str, ...]:
    """[backends] ``key``: a non-empty list of distinct backend names; an estimated target without an Edge TPU
    cannot put ``edgetpu`` first (a measured host may: the chain skips a delegate it cannot load)."""
    order = backends[key]
    if not isinstance(order, list) or not order or any(b not in BACKEND_NAMES for b in order):
        raise ProfileError(f"{src}: [backends] {key} must be a non-empty list drawn from {list(BACKEND_NAMES)}")
    if len(set(order)) != len(order):
        raise ProfileError(f"{src}: [backends] {key} names a backend twice: {order}")
    if order[0] == "edgetpu" and accelerator != "edgetpu" and not measured:
        raise ProfileError(
            f"{src}: [backends] {key}: backend 'edgetpu' comes first but [accelerator] kind is not 'edgetpu'"
        )
    return tuple(order)


def load_profile(name_or_path: str | Path) -> DeviceProfile:
    """Load ``profiles/<name>.toml`` or a TOML file path."""
    path = Path(name_or_path)
    if path.suffix != ".toml":
        path = PROFILES_DIR / f"{name_or_path}.toml"
    if not path.is_file():
        known = sorted(p.stem for p in PROFILES_DIR.glob("*.toml"))
        raise ProfileError(f"device profile {str(name_or_path)!r} not found (known: {known}, or pass a .toml path)")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(f"{path}: not valid TOML ({exc})") from exc
    return parse_profile(data, str(path))


def list_profiles() -> list[str]:
    return sorted(p.stem for p in PROFILES_DIR.glob("*.toml"))
