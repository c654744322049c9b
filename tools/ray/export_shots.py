"""Exports many shots on a Ray cluster: one Ray task per shot (or per range of a long shot's
frames), each running `facesim export` on one animation track, then gathers every task's
outputs and report into one farm report.

    python3 tools/ray/export_shots.py SHOT.json [SHOT.json | DIR ...] --out DIR
        [--format usd,pc2] [--fps 30] [--quality final] [--contact on]
        [--chunk FRAMES [--lead-in 10]]
        [--sample sample_models/ict] [--facesim target/release/facesim]
        [--address ray://HOST:10001 | auto] [--cpus-per-task 1] [--force]

- Shots are track files (facesim-track JSON); a folder stands for the `*.json` tracks in it.
  Shot `NAME.json` is written to `OUT/NAME/` (`NAME.usda`, `NAME.pc2`, …, `NAME.report.json`).
- `--chunk N` splits every shot into ranges of N frames, one task each, written to
  `OUT/NAME/frames-A-B/` (`facesim export --frames A..B --lead-in K`: frames keep their numbers,
  and each range first solves K frames before A without writing them, so it starts from the
  state the whole export has there).
- Without `--address` the script starts a local Ray cluster on this machine; with one it joins
  that cluster (`auto`: the one `ray start` runs here). Every node needs the facesim binary, the
  sample and the tracks at the same paths, and `OUT` on a shared file system.
- A shot (or range) whose report already says it finished with the same settings is not
  exported again, so re-running an interrupted farm continues where it stopped, range by range
  for a chunked shot (`--force` redoes everything).
  `facesim export` itself writes every file under a temporary name first, so an interrupted
  shot leaves nothing under a final name.
- Each task runs with `RAYON_NUM_THREADS` = `--cpus-per-task` and asks Ray for that many CPUs.
- `OUT/farm-report.json` lists every shot (done, skipped or failed, wall seconds, frames,
  unconverged frames, frames with crossings, outputs); the script exits 1 if a shot failed.
"""

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import ray

FARM_FORMAT = "facesim-farm-report"


def shots_of(paths):
    shots = []
    for p in map(Path, paths):
        if p.is_dir():
            shots.extend(sorted(p.glob("*.json")))
        elif p.is_file():
            shots.append(p)
        else:
            sys.exit(f"no track or folder {p}")
    names = [s.stem for s in shots]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        sys.exit(f"two shots share a name (each writes OUT/NAME/): {', '.join(duplicates)}")
    if not shots:
        sys.exit("no shots given")
    return shots


def frame_count(track, fps):
    """`facesim export`'s frame count: t = k/fps for k = 0 … ⌊duration·fps⌋."""
    keys = json.loads(Path(track).read_text())["keys"]
    return int(keys[-1]["time"] * fps + 1e-9) + 1


def tasks_of(shot, args):
    """(range or None, output folder) for each task of a shot."""
    base = (args.out / shot.stem).resolve()
    if args.chunk is None:
        return [(None, base)]
    try:
        total = frame_count(shot, args.fps)
    except (OSError, ValueError, KeyError, IndexError):
        return [(None, base)]  # let `facesim export` say what is wrong with the track
    return [((a, min(a + args.chunk, total)), base / f"frames-{a}-{min(a + args.chunk, total)}")
            for a in range(0, total, args.chunk)]


def settings_of(args):
    return {"fps": args.fps, "quality": args.quality, "contact": args.contact}


def finished(report_path, settings):
    """The shot's report, if a previous run finished it with these settings."""
    try:
        report = json.loads(Path(report_path).read_text())
    except (OSError, ValueError):
        return None
    same = report.get("fps") == settings["fps"]
    if settings["quality"] is not None:
        same &= report.get("quality") == settings["quality"]
    if settings["contact"] is not None:
        same &= report.get("contact") == (settings["contact"] == "on")
    return report if same else None


def summary_of(report):
    return {
        "frames": len(report["frames"]),
        "unconverged": report["unconverged"],
        "crossing_frames": report["crossing_frames"],
        "quality": report["quality"],
        "contact": report["contact"],
    }


@ray.remote
def export_shot(facesim, track, out_dir, sample, formats, settings, frames, lead_in, threads):
    """Runs `facesim export` on one track (or a range of its frames); never raises, so one bad
    shot cannot stop the farm."""
    command = [facesim, "export", track, "--out", out_dir, "--format", formats,
               "--fps", str(settings["fps"]), "--sample", sample]
    if frames is not None:
        command += ["--frames", f"{frames[0]}..{frames[1]}", "--lead-in", str(lead_in)]
    if settings["quality"] is not None:
        command += ["--quality", settings["quality"]]
    if settings["contact"] is not None:
        command += ["--contact", settings["contact"]]
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    start = time.monotonic()
    run = subprocess.run(command, capture_output=True, text=True, env=env)
    result = {
        "shot": Path(track).stem,
        "track": track,
        "range": frames,
        "node": ray.util.get_node_ip_address(),
        "wall_s": round(time.monotonic() - start, 3),
        "command": command,
    }
    report_path = Path(out_dir) / f"{Path(track).stem}.report.json"
    if run.returncode != 0:
        return {**result, "status": "failed", "error": (run.stderr or run.stdout)[-2000:]}
    report = json.loads(report_path.read_text())
    outputs = sorted(str(p) for p in Path(out_dir).iterdir() if not p.name.startswith("."))
    return {**result, "status": "done", **summary_of(report), "outputs": outputs}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("shots", nargs="+", help="track files or folders of them")
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--format", default="usd,pc2")
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--quality", choices=["interactive", "preview", "final"])
    parser.add_argument("--contact", choices=["on", "off"])
    parser.add_argument("--sample", default="sample_models/ict")
    parser.add_argument("--facesim", default="target/release/facesim")
    parser.add_argument("--address", help="a Ray cluster to join (default: start a local one)")
    parser.add_argument("--chunk", type=int, help="frames per task (default: a shot per task)")
    parser.add_argument("--lead-in", type=int, default=10,
                        help="with --chunk: frames solved before each range, not written")
    parser.add_argument("--cpus-per-task", type=int, default=1)
    parser.add_argument("--force", action="store_true", help="export shots that are done too")
    args = parser.parse_args()

    shots = shots_of(args.shots)
    facesim = str(Path(args.facesim).resolve())
    if not os.access(facesim, os.X_OK):
        sys.exit(f"no facesim binary at {facesim} (build it: cargo build --release -p facesim-cli)")
    sample = str(Path(args.sample).resolve())
    settings = settings_of(args)
    args.out.mkdir(parents=True, exist_ok=True)

    ray.init(address=args.address, include_dashboard=False, log_to_driver=False)
    start = time.monotonic()
    results, pending = [], []
    if args.chunk is not None and args.chunk < 1:
        sys.exit("--chunk must be at least 1 frame")
    for shot in shots:
        for frames, out_dir in tasks_of(shot, args):
            report = out_dir / f"{shot.stem}.report.json"
            done = None if args.force else finished(report, settings)
            if done is not None:
                results.append({"shot": shot.stem, "track": str(shot), "range": frames,
                                "status": "skipped", **summary_of(done)})
                continue
            pending.append(export_shot.options(num_cpus=args.cpus_per_task).remote(
                facesim, str(shot.resolve()), str(out_dir), sample, args.format, settings,
                frames, args.lead_in, args.cpus_per_task))
    results.extend(ray.get(pending))
    nodes = len(ray.nodes())
    ray.shutdown()

    results.sort(key=lambda r: (r["shot"], r.get("range") or (0, 0)))
    failed = [r for r in results if r["status"] == "failed"]
    farm = {
        "format": FARM_FORMAT,
        "version": 1,
        "settings": settings,
        "formats": args.format,
        "nodes": nodes,
        "wall_s": round(time.monotonic() - start, 3),
        "shots": results,
        "done": sum(r["status"] == "done" for r in results),
        "skipped": sum(r["status"] == "skipped" for r in results),
        "failed": len(failed),
        "unconverged_frames": sum(r.get("unconverged", 0) for r in results),
    }
    (args.out / "farm-report.json").write_text(json.dumps(farm, indent=2))
    print("| shot | frames | status | written | unconverged | with crossings | wall s |")
    print("|---|---|---|---:|---:|---:|---:|")
    for r in results:
        span = "all" if r.get("range") is None else f"{r['range'][0]}..{r['range'][1]}"
        print(f"| {r['shot']} | {span} | {r['status']} | {r.get('frames', '–')} | "
              f"{r.get('unconverged', '–')} | {r.get('crossing_frames', '–')} | "
              f"{r.get('wall_s', '–')} |")
    print(f"{farm['done']} exported, {farm['skipped']} already done, {farm['failed']} failed "
          f"on {nodes} node(s) in {farm['wall_s']:.1f} s; {args.out / 'farm-report.json'}")
    for r in failed:
        print(f"{r['shot']} failed: {r['error']}", file=sys.stderr)
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
