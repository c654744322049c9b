"""Reads an .rrd written by the editor's rerun logger back with the rerun SDK and checks it
against what the Rust test logged (a JSON file: frames, vertex count, residuals, heatmaps).

Usage: python3 check_rrd.py FILE.rrd EXPECTED.json   (exit 0 and prints "ok" when it matches)
"""

import json
import sys
from collections import defaultdict

import rerun.experimental as rx


def main(rrd: str, expected_path: str) -> None:
    expected = json.load(open(expected_path))
    rows = defaultdict(list)  # entity -> [(frame or None, {column: value})]
    for chunk in rx.RrdReader(rrd).stream().to_chunks():
        batch = chunk.to_record_batch()
        names = [n for n in batch.schema.names if n not in ("rerun.controls.RowId", "log_time")]
        columns = {n: batch.column(n).to_pylist() for n in names}
        for i in range(chunk.num_rows):
            row = {n: columns[n][i] for n in names}
            rows[str(chunk.entity_path)].append((row.pop("frame", None), row))

    def need(cond, message):
        if not cond:
            sys.exit(f"rrd check failed: {message}")

    entities = set(rows)
    for e in ["/face/skin", "/face/crosses", "/face/jaw", "/solver/iterations", "/solver/residual"]:
        need(e in entities, f"entity {e} missing (have {sorted(entities)})")
    for h in expected["heatmaps"]:
        need(f"/face/heatmaps/{h}" in entities, f"heatmap entity {h} missing")

    skin = rows["/face/skin"]
    static = [r for f, r in skin if f is None and r.get("Mesh3D:triangle_indices")]
    need(len(static) == 1, f"one static triangle list expected, got {len(static)}")
    need(len(static[0]["Mesh3D:triangle_indices"]) == expected["triangles"], "triangle count")
    frames = sorted(f for f, r in skin if f is not None and r.get("Mesh3D:vertex_positions"))
    need(frames == expected["frames"], f"frames {frames} != {expected['frames']}")
    for f, r in skin:
        if f is not None:
            need(len(r["Mesh3D:vertex_positions"]) == expected["vertices"], "vertex count")
            need(len(r["Mesh3D:vertex_normals"]) == expected["vertices"], "normal count")
    residuals = {f: r["Scalars:scalars"][0] for f, r in rows["/solver/residual"]}
    for f, value in zip(expected["frames"], expected["residuals"]):
        need(abs(residuals[f] - value) <= 1e-12 * max(1.0, abs(value)), f"residual at frame {f}")
    for h in expected["heatmaps"]:
        colored = [r for f, r in rows[f"/face/heatmaps/{h}"] if f is not None]
        need(len(colored) == len(expected["frames"]), f"heatmap {h} frames")
        need(all(len(r["Mesh3D:vertex_colors"]) == expected["vertices"] for r in colored), f"heatmap {h} colours")
    print("ok")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
