"""A rollout bank's draw log (``draws.jsonl``, written by ``hyperbones rollouts``) summed up.

Prints one Markdown row per garment template and start (draped or carried): draws made, the
share refused (for rise, gap or detachment), files saved, and the median seconds of one draw
spent on its identity (the drape included) and on its rollout; then the bank's whole hours per
saved file (CPU seconds where the log has them, else wall seconds).
Usage: ``python scripts/bank_draws.py BANK [--since YYYY-MM-DDTHH:MM]``.
"""

from __future__ import annotations

import argparse
import statistics
from collections import defaultdict

from hyperbones.errors import HyperbonesError
from hyperbones.training.rollouts import DRAW_LOG, read_draw_log


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bank", help="bank folder (holds draws.jsonl)")
    parser.add_argument("--since", default="", help="only draws made at or after this ISO time")
    args = parser.parse_args()
    try:
        draws = [d for d in read_draw_log(f"{args.bank}/{DRAW_LOG}") if d["made"] >= args.since]
    except HyperbonesError as error:
        raise SystemExit(f"error: {error}") from None
    if not draws:
        raise SystemExit(f"{args.bank}/{DRAW_LOG}: no draws logged{' since ' + args.since if args.since else ''}")
    # CPU seconds (one core's work, blind to other jobs and to a paused process) where every draw
    # has them (records made since commit 61a6d16), wall seconds otherwise.
    cpu = all("rollout_cpu_s" in d for d in draws)
    identity_key, rollout_key = ("identity_cpu_s", "rollout_cpu_s") if cpu else ("identity_s", "rollout_s")
    print(f"seconds: {'CPU time of the bank process' if cpu else 'wall time (older records have no CPU time)'}\n")
    groups: dict[tuple[str, bool], list[dict]] = defaultdict(list)
    for draw in draws:
        groups[(draw["template"], draw["draped"])].append(draw)
    print("| template | start | draws | refused % | saved | median identity s | median rollout s |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for (template, draped), group in sorted(groups.items()):
        refused = sum(bool(d["refused_for"]) for d in group)
        print(f"| {template} | {'draped' if draped else 'carried'} | {len(group)} | {100 * refused / len(group):.0f} "
              f"| {sum(d['file'] is not None for d in group)} "
              f"| {statistics.median(d[identity_key] for d in group):.1f} "
              f"| {statistics.median(d[rollout_key] for d in group):.1f} |")
    seconds = sum(d[identity_key] + d[rollout_key] for d in draws)
    saved = sum(d["file"] is not None for d in draws)
    refused = [d for d in draws if d["refused_for"]]
    wasted = sum(d[identity_key] + d[rollout_key] for d in refused)
    reasons = ", ".join(f"{reason} {sum(reason in d['refused_for'] for d in refused)}"
                        for reason in ("rise", "gap", "detached"))
    print(f"\n{len(draws)} draws, {saved} saved; {len(refused)} refused (for {reasons}); "
          f"{seconds / 3600:.2f} core-hours in draws, {seconds / max(saved, 1):.0f} s per saved rollout "
          f"({wasted / max(seconds, 1) * 100:.0f} % of it on refused draws, "
          f"{sum(d[identity_key] for d in draws) / max(seconds, 1) * 100:.0f} % on identities and drapes)")


if __name__ == "__main__":
    main()
