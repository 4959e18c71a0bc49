#!/usr/bin/env python3
"""The large-canvas generator: `deepcanvas-server replay --tile-to-cells N --seed S`.

Usage: replay_tiled.py PATH/TO/deepcanvas-server

Two real paintings tiled until the canvas holds 300,000 cells: the canvas reaches the count, its
strokes are all painted (none rejected or stopped), the same seed makes the same canvas
(canvas_hash) and another seed another one. Exit 77 (skipped) without $DEEPCANVAS_PAINTINGS.
"""
import json
import os
import subprocess
import sys


def tiled(server, paintings, seed):
    p = subprocess.run([server, "replay", "--tile-to-cells", "300000", "--seed", str(seed),
                        os.path.join(paintings, "demo.apa"), os.path.join(paintings, "dancer.apa"),
                        "--json", "--quiet"], capture_output=True, text=True, timeout=600)
    if p.returncode != 0:
        sys.exit(f"replay --tile-to-cells: exit {p.returncode}\n{p.stderr[-2000:]}")
    return json.loads(p.stdout)


def main():
    server = sys.argv[1]
    paintings = os.environ.get("DEEPCANVAS_PAINTINGS", "")
    if not os.path.exists(os.path.join(paintings, "dancer.apa")):
        print("$DEEPCANVAS_PAINTINGS is not set: skipped")
        sys.exit(77)
    a, b, c = tiled(server, paintings, 3), tiled(server, paintings, 3), tiled(server, paintings, 4)
    print({k: a[k] for k in ("cells", "placements", "strokes", "canvas_hash", "max_depth")})
    if a["cells"] < 300000 or a["placements"] < 1:
        sys.exit("the canvas did not reach 300,000 cells")
    if a["rejected"] or a["stopped"]:
        sys.exit("strokes were rejected or stopped")
    if (a["canvas_hash"], a["cells"]) != (b["canvas_hash"], b["cells"]):
        sys.exit("the same seed made another canvas")
    if a["canvas_hash"] == c["canvas_hash"]:
        sys.exit("another seed made the same canvas")
    print("ok")


if __name__ == "__main__":
    main()
