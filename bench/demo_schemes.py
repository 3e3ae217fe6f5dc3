"""The full demo (pilot, 10 obstacle passes, the shipped trace) once per control scheme.

Prints one row per scheme: exit status, passes, completion time, the per-step and per-tick
speed errors, falls and obstacle contacts (the demo's report), and the wall time. Video is
off (nobody watches; it halves the CPU load). Each run keeps its folder under ``--out``.

Usage: ``.venv/bin/python bench/demo_schemes.py [--schemes paper wave ...] [--out runs/schemes]``
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from bipedtele.control.schemes import scheme_names

DEMO = [sys.executable, "-m", "bipedtele.cli", "demo", "--headless", "--quiet"]
NO_VIDEO = ["--set", "follower.camera_fps=0"]


def _fmt(report: dict[str, float], key: str, spec: str = "{:.2f}") -> str:
    value = report.get(key)
    return "-" if value is None else spec.format(value)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--schemes", nargs="+", default=scheme_names())
    ap.add_argument("--out", default="runs/schemes")
    args = ap.parse_args()
    out = Path(args.out)
    print(
        "| scheme | rc | passes | completion [s] | fwd / turn error per step | per tick | falls | contacts | wall [s] |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for scheme in args.schemes:
        run_dir, report = out / scheme, out / f"{scheme}.json"
        t0 = time.monotonic()
        proc = subprocess.run(
            [*DEMO, "--scheme", scheme, "--run-dir", str(run_dir), "--json", str(report), *NO_VIDEO],
            capture_output=True,
            text=True,
            timeout=900,
        )
        wall = time.monotonic() - t0
        r = json.loads(report.read_text()) if report.exists() else {}
        print(
            f"| {scheme} | {proc.returncode} | {r.get('passes', '-')} | {_fmt(r, 'completion_s', '{:.1f}')} | "
            f"{_fmt(r, 'forward_error_cm_s')} / {_fmt(r, 'turn_error_deg_s')} | "
            f"{_fmt(r, 'forward_error_instant_cm_s')} / {_fmt(r, 'turn_error_instant_deg_s')} | "
            f"{r.get('falls', '-')} | {r.get('collisions', '-')} | {wall:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
