"""Where a flight's resident memory goes: run a command, sample its /proc/PID/smaps, break the peak down.

    python docs/runtime/memory_breakdown.py [--out runs/memory] -- edge-explorer run --time-limit-s 60 --no-return

Samples the command's process every ``--every-s`` seconds (``/proc/PID/smaps``: every mapping's resident pages) and
keeps the sample with the most resident memory. At that sample it splits the RSS as Linux does — ``anon`` (heap,
arrays, numba's machine code, the libraries' written data) against ``file`` (mapped pages of files: the shared
libraries' code, page cache) — and lists the files and the anonymous regions by size, so the libraries a flight
maps and their cost are visible. Also prints the kernel's own high-water mark (``VmHWM``) and writes everything to
``--out``/``memory.json``. The sampled peak can miss a peak shorter than the sampling period; VmHWM does not.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path


def sample(pid: int) -> dict[str, float] | None:
    """Resident kB per mapping name (file path or ``[anon]``/``[heap]``/…), split into ``anon:`` and ``file:``."""
    try:
        text = Path(f"/proc/{pid}/smaps").read_text()
    except (OSError, ProcessLookupError):
        return None
    out: dict[str, float] = defaultdict(float)
    name, rss = "[anon]", 0
    for line in text.splitlines():
        first = line.split(maxsplit=5)
        if "-" in first[0] and len(first) >= 5 and not first[0].endswith(":"):
            name = first[5] if len(first) == 6 else "[anon]"
        elif first[0] == "Rss:":
            rss = int(first[1])
        elif first[0] == "Anonymous:":
            anon = int(first[1])
            out[f"anon:{_short(name)}"] += anon
            out[f"file:{_short(name)}"] += rss - anon
    return {k: v for k, v in out.items() if v}


def _short(name: str) -> str:
    """A library's path from its package folder on (``site-packages/numba/…`` → ``numba/…``)."""
    return name.split("site-packages/", 1)[-1]


def high_water_kb(pid: int) -> int | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("runs/memory"), help="output folder (default runs/memory)")
    parser.add_argument("--every-s", type=float, default=0.5, help="sampling period (default 0.5 s)")
    parser.add_argument("--top", type=int, default=15, help="rows per table (default 15)")
    parser.add_argument("command", nargs=argparse.REMAINDER, help="-- the command to run")
    args = parser.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("give the command after --")
    process = subprocess.Popen(command)
    peak: dict[str, float] = {}
    peak_t_s, hwm_kb, t0 = 0.0, 0, time.monotonic()
    while process.poll() is None:
        now = sample(process.pid)
        hwm_kb = max(hwm_kb, high_water_kb(process.pid) or 0)
        if now is not None and sum(now.values()) > sum(peak.values()):
            peak, peak_t_s = now, time.monotonic() - t0
        time.sleep(args.every_s)
    anon = sum(v for k, v in peak.items() if k.startswith("anon:"))
    file = sum(v for k, v in peak.items() if k.startswith("file:"))
    print(f"exit code {process.returncode}; VmHWM {hwm_kb / 1024:.0f} MB; sampled peak at {peak_t_s:.1f} s: ")
    print(f"{(anon + file) / 1024:.0f} MB = {anon / 1024:.0f} MB anon + {file / 1024:.0f} MB file-backed")
    for kind in ("file", "anon"):
        rows = sorted(((v, k.split(":", 1)[1]) for k, v in peak.items() if k.startswith(kind + ":")), reverse=True)
        print(f"\n{kind}-backed, largest first (MB):")
        for kb, name in rows[: args.top]:
            print(f"  {kb / 1024:7.1f}  {name}")
    args.out.mkdir(parents=True, exist_ok=True)
    doc = {
        "command": command,
        "exit_code": process.returncode,
        "vm_hwm_mb": hwm_kb / 1024,
        "sampled_peak": {"t_s": peak_t_s, "anon_mb": anon / 1024, "file_mb": file / 1024},
        "mappings_kb": dict(sorted(peak.items(), key=lambda kv: -kv[1])),
    }
    (args.out / "memory.json").write_text(json.dumps(doc, indent=1) + "\n")
    return process.returncode


if __name__ == "__main__":
    sys.exit(main())
