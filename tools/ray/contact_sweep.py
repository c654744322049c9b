#!/usr/bin/env python3
"""Runs the random-code contact sweep as shards on Ray and merges their results.

Each shard is one Ray task: `facesim bench contact --sweep CODES --sweep-seed SEED` (the
bundled sample's neutral face, interactive preset) with its own seed, so shards are
independent sweeps whose codes never repeat; the 1,008-code acceptance run is 63 shards of
16. Every shard writes its JSON report to `OUT/`; the merged counts, the frame-time
percentiles over all frames and the CPU time go to `OUT/sweep-report.json` and a table.

    python3 tools/ray/contact_sweep.py --shards 63 --codes 16 --out out/sweep
    python3 tools/ray/contact_sweep.py --shards 63 --codes 16 --out /shared/sweep --address auto

Without `--address` it starts a local Ray cluster on this machine; with one it joins that
cluster (every node needs the facesim binary and the repository, with the sample, at the same
paths). A shard whose report is already in `OUT/` with the same settings is not run again, so
a stopped sweep continues where it stopped (`--force` runs them all). A failed shard is
reported without stopping the others, and the driver exits with status 1.
"""

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import ray

SWEEP_FORMAT = "facesim-sweep-farm"
KINDS = ("contact", "no_contact")
SUMMED = ("frames", "ok", "converged", "from_rest", "inverted", "intersecting")


def shard_path(out, args, seed):
    """The shard's report: its settings in its name, so a rerun with other settings never
    takes it for done."""
    low, high = args.range
    return out / f"shard-{args.mode}-{low:g}_{high:g}-n{args.codes}-seed{seed}.json"


def finished(path, codes):
    """The shard's report, if a previous run wrote it whole."""
    try:
        report = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    return report if len(report.get("outcomes", [])) == codes else None


@ray.remote
def sweep_shard(facesim, root, seed, args, path, threads):
    """One shard: `facesim bench contact --sweep` run from the repository root; never raises,
    so one bad shard cannot stop the others."""
    low, high = args["range"]
    command = [facesim, "bench", "contact", "--sweep", str(args["codes"]),
               "--sweep-seed", str(seed), "--sweep-mode", args["mode"],
               "--sweep-range", f"{low},{high}", "--json", str(path)]
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    start = time.monotonic()
    run = subprocess.run(command, capture_output=True, text=True, env=env, cwd=root)
    result = {"seed": seed, "node": ray.util.get_node_ip_address(),
              "wall_s": round(time.monotonic() - start, 3), "command": command}
    if run.returncode != 0:
        return {**result, "status": "failed", "error": (run.stderr or run.stdout)[-2000:]}
    return {**result, "status": "done", "report": json.loads(Path(path).read_text())}


def percentile(sorted_values, p):
    """The nearest-rank percentile of sorted values (None when empty)."""
    if not sorted_values:
        return None
    rank = min(len(sorted_values) - 1, int(p / 100 * len(sorted_values)))
    return sorted_values[rank]


def merge(reports):
    """The shards' counts summed and their frame times pooled, per kind of solve."""
    merged = {}
    for kind in KINDS:
        counts = [r[kind] for r in reports if r.get(kind) is not None]
        if not counts:
            continue
        times = sorted(t for c in counts for t in c.get("frame_ms", []))
        merged[kind] = {
            **{key: sum(c[key] for c in counts) for key in SUMMED},
            "other_errors": [e for c in counts for e in c["other_errors"]],
            "frame_ms": {"median": percentile(times, 50), "p95": percentile(times, 95),
                         "p99": percentile(times, 99), "max": times[-1] if times else None},
            "cpu_minutes": round(sum(times) / 60e3, 2),
        }
    return merged


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--shards", type=int, default=63)
    parser.add_argument("--codes", type=int, default=16, help="codes per shard")
    parser.add_argument("--first-seed", type=int, default=101,
                        help="shard k uses seed FIRST_SEED + k")
    parser.add_argument("--mode", choices=["contact", "no-contact", "compare"],
                        default="contact")
    parser.add_argument("--range", default="-0.5,1.5", help="the sliders' range, LOW,HIGH")
    parser.add_argument("--root", default=".", help="the repository root (holds the sample)")
    parser.add_argument("--facesim", default="target/release/facesim")
    parser.add_argument("--address", help="a Ray cluster to join (default: start a local one)")
    parser.add_argument("--cpus-per-task", type=int, default=1)
    parser.add_argument("--force", action="store_true", help="run shards that are done too")
    args = parser.parse_args()

    try:
        args.range = tuple(float(v) for v in args.range.split(","))
        assert len(args.range) == 2 and args.range[0] <= args.range[1]
    except (ValueError, AssertionError):
        sys.exit(f"--range takes LOW,HIGH with LOW <= HIGH, got {args.range!r}")
    if args.shards < 1 or args.codes < 1:
        sys.exit("--shards and --codes must be at least 1")
    facesim = str(Path(args.facesim).resolve())
    if not os.access(facesim, os.X_OK):
        sys.exit(f"no facesim binary at {facesim} (build it: cargo build --release -p facesim-cli)")
    root = str(Path(args.root).resolve())
    args.out.mkdir(parents=True, exist_ok=True)
    settings = {"codes": args.codes, "mode": args.mode, "range": list(args.range)}

    ray.init(address=args.address, include_dashboard=False, log_to_driver=False)
    start = time.monotonic()
    results, pending = [], []
    for seed in range(args.first_seed, args.first_seed + args.shards):
        path = shard_path(args.out, args, seed)
        done = None if args.force else finished(path, args.codes)
        if done is not None:
            results.append({"seed": seed, "status": "skipped", "report": done})
            continue
        pending.append(sweep_shard.options(num_cpus=args.cpus_per_task).remote(
            facesim, root, seed, settings, str(path.resolve()), args.cpus_per_task))
    results.extend(ray.get(pending))
    nodes = len(ray.nodes())
    ray.shutdown()

    results.sort(key=lambda r: r["seed"])
    reports = [r["report"] for r in results if "report" in r]
    failed = [r for r in results if r["status"] == "failed"]
    farm = {
        "format": SWEEP_FORMAT,
        "version": 1,
        "settings": settings,
        "nodes": nodes,
        "wall_s": round(time.monotonic() - start, 3),
        "shards": [{k: v for k, v in r.items() if k != "report"} for r in results],
        "done": sum(r["status"] == "done" for r in results),
        "skipped": sum(r["status"] == "skipped" for r in results),
        "failed": len(failed),
        **merge(reports),
    }
    (args.out / "sweep-report.json").write_text(json.dumps(farm, indent=2))
    print("| solves | frames | ok | converged | from rest | inverted | intersecting | errors "
          "| median ms | p95 ms | p99 ms | max ms | CPU min |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for kind in KINDS:
        if kind in farm:
            c, t = farm[kind], farm[kind]["frame_ms"]
            print(f"| {kind.replace('_', ' ')} | {c['frames']} | {c['ok']} | {c['converged']} | "
                  f"{c['from_rest']} | {c['inverted']} | {c['intersecting']} | "
                  f"{len(c['other_errors'])} | {t['median']:.1f} | {t['p95']:.1f} | "
                  f"{t['p99']:.1f} | {t['max']:.1f} | {c['cpu_minutes']} |")
    print(f"{farm['done']} shards run, {farm['skipped']} already done, {farm['failed']} failed "
          f"on {nodes} node(s) in {farm['wall_s']:.1f} s; {args.out / 'sweep-report.json'}")
    for r in failed:
        print(f"shard seed {r['seed']} failed: {r['error']}", file=sys.stderr)
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
