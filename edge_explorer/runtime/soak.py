"""The long soak: ``edge-explorer run --soak 30m`` flies closed-loop flights back to back in one process.

Each flight is a full :func:`~edge_explorer.runtime.flight.fly` of the simulated drone (its own outputs in
``--out``/``flightNNN/``), flight ``k`` with the benchmark's noise seed of run ``k``; the last one's exploration time
is cut to what is left of the soak. A thread samples the process's resident memory (``/proc/self/status``: total,
allocated, mapped files) every ``sample_every_s`` for the whole soak. ``soak.json`` holds the samples, every
flight's ending, decisions, holds and collisions, and the totals; ``soak.png`` plots the RSS over time with the
flight boundaries.

The verdict (exit code 0 when it passes, docs/design.md's reliability list): no flight crashed, 0 collisions, and RSS
grew by less than :data:`MAX_RSS_GROWTH` from the sixth of the soak on (minute 5 of 30) to its end — after the
first flights have loaded what every flight uses, the process must not keep growing. A SIGINT or SIGTERM ends the
flight in progress with a hold and the soak after it.
"""

from __future__ import annotations

import argparse
import re
import threading
import time
import traceback
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from edge_explorer.runtime.options import RunOptions

if TYPE_CHECKING:
    from edge_explorer.runtime.flight import Simulation

MAX_RSS_GROWTH = 0.05  # RSS growth allowed from the sixth of the soak to its end
DEFAULT_FLIGHT_TIME_LIMIT_S = 600.0  # a flight's exploration time unless --time-limit-s says otherwise
MIN_FLIGHT_S = 2.0  # less than this left of the soak: no new flight
_UNITS_S = {"": 1.0, "s": 1.0, "m": 60.0, "h": 3600.0}


def parse_duration(text: str) -> float:
    """An argparse type: ``30m``, ``90s``, ``1.5h`` or plain seconds → seconds (positive and finite)."""
    match = re.fullmatch(r"\s*(\d+(?:\.\d*)?|\.\d+)\s*([smh]?)\s*", text)
    if match is None or float(match.group(1)) <= 0:
        raise argparse.ArgumentTypeError(f"expected a duration such as 30m, 90s or 1.5h, got {text!r}")
    return float(match.group(1)) * _UNITS_S[match.group(2)]


class RssSampler:
    """A thread that records ``(t_s, rss_mb, anon_mb, file_mb)`` of this process every ``every_s`` seconds."""

    def __init__(self, every_s: float) -> None:
        self.every_s = every_s
        self.samples: list[tuple[float, float, float, float]] = []
        self._t0_s = time.monotonic()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="soak-rss", daemon=True)

    def __enter__(self) -> RssSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._sample()

    def _run(self) -> None:
        while True:
            self._sample()
            if self._stop.wait(self.every_s):
                return

    def _sample(self) -> None:
        from edge_explorer.runtime.flight import resident_memory_mb

        rss = resident_memory_mb()
        anon, file = rss.get("anon", 0.0), rss.get("file", 0.0)
        self.samples.append((time.monotonic() - self._t0_s, anon + file + rss.get("shmem", 0.0), anon, file))


def rss_growth(samples: list[tuple[float, float, float, float]], duration_s: float) -> float | None:
    """Relative RSS growth from the first sample at or after a sixth of ``duration_s`` to the last sample."""
    later = [s for s in samples if s[0] >= duration_s / 6]
    if len(later) < 2:
        return None
    return later[-1][1] / later[0][1] - 1.0


def run_soak(
    options: RunOptions, duration_s: float, sample_every_s: float = 5.0, simulation: Simulation | None = None
) -> int:
    """Fly flights back to back for ``duration_s``; write ``soak.json`` and ``soak.png`` in ``options.out_dir``.
    Returns the exit code: 0 when the soak passed (see the module docstring), 1 otherwise. ``simulation``: the
    simulated drone the flights fly (:class:`edge_explorer.sim.flight.SimulatedFlight`, built by the caller)."""
    from edge_explorer.runtime.flight import fly

    out = options.out_dir
    out.mkdir(parents=True, exist_ok=True)
    limit_s = options.time_limit_s or DEFAULT_FLIGHT_TIME_LIMIT_S
    flights: list[dict[str, Any]] = []
    start_s = time.monotonic()
    with RssSampler(sample_every_s) as sampler:
        while (left_s := duration_s - (time.monotonic() - start_s)) >= MIN_FLIGHT_S:
            k = len(flights)
            flight = replace(
                options,
                out_dir=out / f"flight{k:03d}",
                run_index=options.run_index + k,
                time_limit_s=min(limit_s, left_s),
                progress=False,
            )
            record: dict[str, Any] = {"flight": k, "start_s": time.monotonic() - start_s}
            try:
                summary = fly(flight, simulation)
            except Exception as exc:  # noqa: BLE001 - a crash is the soak's finding: recorded, then the soak ends
                traceback.print_exc()
                flights.append({**record, "crash": f"{type(exc).__name__}: {exc}"})
                break
            flights.append({**record, **_flight_figures(summary), "end_s": time.monotonic() - start_s})
            if summary["ending"].startswith("interrupted"):
                break
    report = soak_report(flights, sampler.samples, duration_s, time.monotonic() - start_s)
    _write_outputs(out, report)
    print(
        f"soak: {report['flights']} flights in {report['wall_s'] / 60:.1f} min, {report['decisions']} decisions, "
        f"{report['holds']} holds, {report['collisions']} collisions, {report['crashes']} crashes; RSS "
        f"{report['rss_mb']['first']:.0f} → {report['rss_mb']['last']:.0f} MB (max {report['rss_mb']['max']:.0f}), "
        f"growth after the first sixth {_percent(report['rss_growth'])}: {'PASS' if report['passed'] else 'FAIL'} "
        f"({out / 'soak.json'}, {out / 'soak.png'})",
        flush=True,
    )
    return 0 if report["passed"] else 1


def _flight_figures(summary: dict[str, Any]) -> dict[str, Any]:
    return {
        "ending": summary["ending"],
        "coverage": summary["coverage"],
        "decisions": summary["decisions"],
        "holds": len(summary["holds"]),
        "hold_reasons": sorted({h["reason"] for h in summary["holds"]}),
        "collisions": summary["collisions"],
        "frames_dropped": sum(summary["frames_dropped"].values()),
        "decision_p95_ms": (summary["decision_latency_ms"] or {}).get("p95"),
    }


def soak_report(
    flights: list[dict[str, Any]], samples: list[tuple[float, float, float, float]], duration_s: float, wall_s: float
) -> dict[str, Any]:
    """The soak's figures (``soak.json``) from its flights and RSS samples."""
    growth = rss_growth(samples, duration_s)
    crashes = sum(1 for f in flights if "crash" in f)
    collisions = sum(f.get("collisions") or 0 for f in flights)
    rss = [s[1] for s in samples]
    return {
        "format": "edge-explorer/soak",
        "duration_s": duration_s,
        "wall_s": wall_s,
        "flights": len(flights),
        "decisions": sum(f.get("decisions", 0) for f in flights),
        "holds": sum(f.get("holds", 0) for f in flights),
        "collisions": collisions,
        "crashes": crashes,
        "rss_mb": {"first": rss[0], "last": rss[-1], "max": max(rss)} if rss else None,
        "rss_growth": growth,
        "rss_growth_from_s": duration_s / 6,
        "max_rss_growth": MAX_RSS_GROWTH,
        "passed": crashes == 0 and collisions == 0 and growth is not None and growth < MAX_RSS_GROWTH,
        "samples": [{"t_s": t, "rss_mb": r, "anon_mb": a, "file_mb": f} for t, r, a, f in samples],
        "per_flight": flights,
    }


def _duration(seconds: float) -> str:
    return f"{seconds / 60:.0f} min" if seconds >= 120 else f"{seconds:.0f} s"


def _percent(value: float | None) -> str:
    return "–" if value is None else f"{100 * value:+.1f} %"


def _write_outputs(out: Path, report: dict[str, Any]) -> None:
    from edge_explorer.cli_support import write_json
    from edge_explorer.runtime.flight_summary import in_fresh_process

    write_json(out / "soak.json", report)
    in_fresh_process(plot_soak, out / "soak.png", report)


def plot_soak(path: Path, report: dict[str, Any]) -> None:
    """RSS (total, allocated, mapped files) over the soak, the flights' starts as vertical lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    samples = report["samples"]
    minutes = [s["t_s"] / 60 for s in samples]
    fig, ax = plt.subplots(figsize=(9, 4.5))
    for key, label in (("rss_mb", "resident"), ("anon_mb", "allocated (anon)"), ("file_mb", "mapped files")):
        ax.plot(minutes, [s[key] for s in samples], label=label)
    for flight in report["per_flight"]:
        ax.axvline(flight["start_s"] / 60, color="0.85", lw=0.8, zorder=0)
    ax.axvline(report["rss_growth_from_s"] / 60, color="tab:red", ls="--", lw=1, label="growth measured from here")
    ax.set_xlabel("soak time (min)")
    ax.set_ylabel("MB")
    ax.set_ylim(bottom=0)
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(
        f"soak {_duration(report['duration_s'])}: {report['flights']} flights, {report['decisions']} decisions, "
        f"{report['holds']} holds, {report['collisions']} collisions, {report['crashes']} crashes; RSS growth "
        f"{_percent(report['rss_growth'])}",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
