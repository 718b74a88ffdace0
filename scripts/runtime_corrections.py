"""What each of the runtime's corrections buys for one Module A (#28 item 4), on the validation set.

Runs ``hyperbones eval`` on the validation split (24 runs: two clips x two bodies x six
garments, 1,500 vertices) for the full runtime, Module A alone (``hyperbones-raw``), and the
runtime with each correction switched off or shrunk alone (``--runtime``), then prints their means in
one Markdown table, each against the full runtime. An eval already in the output folder is not
run again, so the script resumes where it stopped; the cost of each correction is its stage in
``hyperbones bench --profile`` (not measured here: this is about what it buys).

Usage: ``python scripts/runtime_corrections.py --out DIR [--checkpoint CKPT]`` (default: the
shipped model). The 2026-11-29 baseline (shipped model): docs/experiments/2026-11-29-realtime-runtime-3.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

GARMENTS = "tshirt,tshirt-open,pants,long-skirt,dress,tight-dress"
VARIANTS = {  # name: (method, --runtime settings, what is off)
    "full": ("hyperbones", "", "nothing (the runtime as the checkpoint stores it)"),
    "no-follow": ("hyperbones", "follow=1,loose_follow=1", "the follow"),
    "no-untangling": ("hyperbones", "untangle=false", "untangling"),
    "one-round": ("hyperbones", "contact_rounds=1", "the second contact round"),
    "no-projection": ("hyperbones", "projection_iterations=0", "edge projection (push-out and proxy sweeps stay)"),
    "three-iterations": ("hyperbones", "projection_iterations=3", "two of the five projection iterations"),
    "eight-sweeps": ("hyperbones", "proxy_sweeps=8", "seven of the proxy's 15 edge sweeps"),
    "no-sweeps": ("hyperbones", "proxy_sweeps=0", "the proxy's edge sweeps"),
    "no-conv-mlp": ("hyperbones", "conv_mlp=false", "Module A's Conv-MLP (the bones' garment goes in)"),
    "module-a-alone": ("hyperbones-raw", "", "everything after Module A"),
}
METRICS = (("edge_error_pct", "ε_e %", "{:.3f}"), ("area_error_pct", "ε_a %", "{:.3f}"),
           ("collision_pct", "ε_c %", "{:.4f}"), ("inertia", "inertia J", "{:.5f}"),
           ("detached_pct", "detached %", "{:.3f}"), ("strain", "strain J", "{:.3f}"))


def evaluate(name: str, out: Path, checkpoint: str | None) -> list[dict]:
    """The runs of one variant (of its method): its report.json, made by ``hyperbones eval`` unless
    already there (an eval of both methods may serve as ``full`` and ``module-a-alone``)."""
    report = out / name / "report.json"
    if not report.exists():
        method, settings, _ = VARIANTS[name]
        command = [sys.executable, "-m", "hyperbones.cli", "eval", "--methods", method, "--garments", GARMENTS,
                   "--split", "validation", "--vertices", "1500", "--device", "cpu", "--out", str(out / name),
                   "--quiet"]
        command += ["--checkpoint", checkpoint] if checkpoint else []
        command += ["--runtime", settings] if settings else []
        print(f"{name}: {' '.join(command[1:])}", flush=True)
        (out / name).mkdir(parents=True, exist_ok=True)
        with open(out / name / "eval.log", "w") as log:  # the eval's own table, beside its report
            done = subprocess.run(command, stdout=log, env={**os.environ, "OMP_NUM_THREADS": "1"})
        if done.returncode:
            raise SystemExit(f"error: {name}: hyperbones eval exited {done.returncode} "
                             f"(its output: {out / name}/eval.log)")
    method = VARIANTS[name][0]
    return [run for run in json.loads(report.read_text()) if run["method"] == method]


def mean(runs: list[dict], key: str) -> float:
    values = [run[key] for run in runs if run.get(key) is not None]
    return sum(values) / len(values)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, type=Path, help="folder for the evals (one subfolder a variant)")
    parser.add_argument("--checkpoint", help="HyperBones checkpoint (default: the shipped model)")
    parser.add_argument("--variants", default=",".join(VARIANTS), help=f"comma list of {', '.join(VARIANTS)}")
    args = parser.parse_args()
    names = args.variants.split(",")
    unknown = sorted(set(names) - set(VARIANTS))
    if unknown:
        parser.error(f"unknown variants {', '.join(unknown)}; known: {', '.join(VARIANTS)}")
    runs = {name: evaluate(name, args.out, args.checkpoint) for name in dict.fromkeys(["full", *names])}
    print("\n| off | `--runtime` | " + " | ".join(label for _, label, _ in METRICS) + " |")
    print("|---|---|" + "---:|" * len(METRICS))
    for name in runs:
        method, settings, off = VARIANTS[name]
        cells = []
        for key, _, fmt in METRICS:
            value, full = mean(runs[name], key), mean(runs["full"], key)
            change = f" ({100 * (value / full - 1):+.0f} %)" if name != "full" and full else ""
            cells.append(fmt.format(value) + change)
        where = f"method `{method}`" if method != "hyperbones" else (f"`{settings}`" if settings else "–")
        print(f"| {off} | {where} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
