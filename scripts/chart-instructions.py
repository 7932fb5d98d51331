#!/usr/bin/env python3
"""Counts the instructions behind the chart's summary: for each scene and N = 4, 6, 8, jitter
N×N against the cheapest adaptive setting that reaches its error.

    scripts/chart-instructions.py [CHART_CSV]

It reads the chart's CSV (default bench/results/chart.csv, written by `tessera-bench chart`),
picks the settings as the chart's summary does (the fastest adaptive point whose RMSE is at
most jitter N×N's), and runs each as a whole `tessera-render --threads 1` process under
`valgrind --tool=callgrind` (parsing and PNG encoding included). It prints a Markdown table:
instructions in millions for both, and their ratio. Instructions do not vary from run to
run as times do, so the ratio checks the chart's timed speed-ups.

Needs valgrind and a release build of tessera-render (`cargo build --release --bin
tessera-render`); the scenes are bench/scenes/<scene>.ray.
"""

import csv
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RENDER = ROOT / "target" / "release" / "tessera-render"


def sampler_args(config):
    """`jitter 4x4` or `adaptive 3x3 t=0.1` as tessera-render's flags."""
    m = re.fullmatch(r"(jitter|adaptive) (\d+)x\d+(?: t=([0-9.]+))?", config)
    if not m:
        raise ValueError(f"not a jitter or adaptive setting: {config}")
    args = ["--sampler", m.group(1), "--samples", m.group(2)]
    if m.group(3):
        args += ["--threshold", m.group(3)]
    return args


def instructions(scene, config):
    """Instructions of one whole render, from callgrind's summary line."""
    cmd = [
        "valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null",
        str(RENDER), "--threads", "1", "-q", "-o", "/dev/null",
        str(ROOT / "bench" / "scenes" / f"{scene}.ray"),
    ] + sampler_args(config)
    run = subprocess.run(cmd, capture_output=True, text=True, check=True)
    m = re.search(r"Collected : (\d+)", run.stderr)
    if not m:
        raise RuntimeError(f"no instruction count from callgrind:\n{run.stderr}")
    return int(m.group(1))


def main():
    path = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "bench" / "results" / "chart.csv"
    rows = list(csv.DictReader(path.open()))
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    print("| scene | N | jitter N×N | cheapest adaptive | instructions (millions) | ratio |")
    print("| --- | ---: | --- | --- | ---: | ---: |")
    for scene in scenes:
        points = [r for r in rows if r["scene"] == scene]
        for n in (4, 6, 8):
            jitter = next((p for p in points if p["config"] == f"jitter {n}x{n}"), None)
            if jitter is None:
                continue
            reaching = [
                p for p in points
                if p["family"].startswith("adaptive") and float(p["rmse"]) <= float(jitter["rmse"])
            ]
            if not reaching:
                print(f"| {scene} | {n} | {jitter['config']} | none reaches it | | |")
                continue
            best = min(reaching, key=lambda p: float(p["time_ms"]))
            j = instructions(scene, jitter["config"])
            a = instructions(scene, best["config"])
            print(
                f"| {scene} | {n} | {jitter['config']} | {best['config']} | "
                f"{j / 1e6:.1f} → {a / 1e6:.1f} | {j / a:.2f}× |",
                flush=True,
            )


if __name__ == "__main__":
    main()
