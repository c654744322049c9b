"""Reads an .rrd written by `facesim-editor export --format rrd` back with the rerun SDK and
checks it: the skin mesh at frames 0 … N-1 on the `frame` timeline (with the track's time on
the `time` timeline), every frame with all vertices and normals, one static triangle list.

Usage: python3 check_export_rrd.py FILE.rrd FRAMES VERTICES TRIANGLES FPS   (prints "ok")
"""

import sys
from collections import defaultdict

import pyarrow as pa
import rerun.experimental as rx


def main(rrd, frames, vertices, triangles, fps):
    def need(cond, message):
        if not cond:
            sys.exit(f"rrd check failed: {message}")

    rows = defaultdict(list)
    for chunk in rx.RrdReader(rrd).stream().to_chunks():
        batch = chunk.to_record_batch()
        names = [n for n in batch.schema.names if n not in ("rerun.controls.RowId", "log_time")]
        columns = {}
        for n in names:
            column = batch.column(n)
            if pa.types.is_duration(column.type):  # the `time` timeline, as integer nanoseconds
                column = column.cast(pa.int64())
            columns[n] = column.to_pylist()
        for i in range(chunk.num_rows):
            rows[str(chunk.entity_path)].append({n: columns[n][i] for n in names})
    skin = rows["/face/skin"]
    static = [r for r in skin if r.get("frame") is None and r.get("Mesh3D:triangle_indices")]
    need(len(static) == 1 and len(static[0]["Mesh3D:triangle_indices"]) == triangles, "static triangles")
    moving = sorted((r for r in skin if r.get("frame") is not None), key=lambda r: r["frame"])
    need([r["frame"] for r in moving] == list(range(frames)), f"frames {[r['frame'] for r in moving]}")
    for r in moving:
        need(len(r["Mesh3D:vertex_positions"]) == vertices, "vertex count")
        need(len(r["Mesh3D:vertex_normals"]) == vertices, "normal count")
        t = r.get("time")
        need(t is not None, "no time timeline")
        seconds = t / 1e9
        need(abs(seconds - r["frame"] / fps) < 1e-6, f"frame {r['frame']} at {seconds} s")
    need("/solver/iterations" in rows and "/face/jaw" in rows, f"entities {sorted(rows)}")
    print("ok")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5]))
