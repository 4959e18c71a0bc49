#!/usr/bin/env python3
"""GET /metrics of a real server with two canvases, read by Prometheus's own parser
(python3-prometheus-client, Debian).

Usage: metrics_scrape.py PATH/TO/deepcanvas-server

Starts `deepcanvas-server serve --listen 127.0.0.1:0 --canvas a --canvas b`, fetches /metrics
over HTTP and checks that:
  * every family has a declared type (a sample outside its family's HELP/TYPE block reads as a
    family of type "unknown") and no family name is declared twice;
  * every family with a `canvas` label carries it on every sample and has samples for both
    canvases; the per-canvas families the operations guide names are among them;
  * the server-wide families carry no `canvas` label;
  * the text has one `# TYPE` line per family.
Exit 0: pass; 1: fail; 77: skipped (python3-prometheus-client missing).
"""
import collections
import subprocess
import sys
import threading
import urllib.request

try:
    from prometheus_client.parser import text_string_to_metric_families
except ImportError:
    print("SKIP: python3 module 'prometheus_client' is missing "
          "(Debian package python3-prometheus-client)")
    sys.exit(77)

CANVASES = {"a", "b"}
# Per-canvas and server-wide families that must be present (parser names: a counter's family
# drops the _total suffix).
PER_CANVAS = {"deepcanvas_strokes", "deepcanvas_live_cells", "deepcanvas_step_seconds",
              "deepcanvas_published_epoch"}
SERVER_WIDE = {"deepcanvas_connections", "deepcanvas_sessions",
               "deepcanvas_stroke_to_first_block_seconds"}


def start_server(server):
    proc = subprocess.Popen([server, "serve", "--in-memory", "--listen", "127.0.0.1:0", "--canvas", "a",
                             "--canvas", "b", "--edge", "8", "--max-depth", "10"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    for line in proc.stderr:
        if "event=listening" in line:
            # Keep reading the log so that the server never blocks on a full pipe.
            threading.Thread(target=lambda: proc.stderr.read(), daemon=True).start()
            return proc, int(line.split("port=")[1].split()[0])
    proc.wait()
    raise AssertionError(f"server exited with {proc.returncode} before listening")


def check(text):
    failures = []
    families = list(text_string_to_metric_families(text))
    names = collections.Counter(f.name for f in families)
    for f in families:
        if f.type == "unknown":
            failures.append(f"family {f.name} has no TYPE (sample {f.samples[0].name})")
    for name, n in names.items():
        if n > 1:
            failures.append(f"family {name} appears {n} times")
    per_canvas = set()
    for f in families:
        labelled = [s for s in f.samples if "canvas" in s.labels]
        if not labelled:
            continue
        per_canvas.add(f.name)
        if len(labelled) != len(f.samples):
            failures.append(f"family {f.name}: some samples lack the canvas label")
        seen = {s.labels["canvas"] for s in labelled}
        if seen != CANVASES:
            failures.append(f"family {f.name}: canvas labels {sorted(seen)}, want a and b")
    for name in sorted(PER_CANVAS - per_canvas):
        failures.append(f"per-canvas family {name} missing or without canvas labels")
    for name in sorted(SERVER_WIDE):
        if name not in names:
            failures.append(f"server-wide family {name} missing")
        elif name in per_canvas:
            failures.append(f"server-wide family {name} has a canvas label")
    type_lines = collections.Counter(
        line.split()[2] for line in text.splitlines() if line.startswith("# TYPE "))
    for name, n in type_lines.items():
        if n > 1:
            failures.append(f"# TYPE {name} written {n} times")
    return failures, len(families), len(per_canvas)


def main():
    if len(sys.argv) != 2:
        print(__doc__)
        return 2
    proc, port = start_server(sys.argv[1])
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=30) as r:
            content_type = r.headers.get("Content-Type", "")
            text = r.read().decode("utf-8")
    finally:
        proc.terminate()
        proc.wait(timeout=60)
    failures, n_families, n_per_canvas = check(text)
    if not content_type.startswith("text/plain"):
        failures.append(f"Content-Type {content_type!r}, want text/plain")
    if proc.returncode != 0:
        failures.append(f"server exit code {proc.returncode} after SIGTERM")
    for f in failures:
        print("FAIL:", f)
    if failures:
        return 1
    print(f"ok: {n_families} families, {n_per_canvas} per canvas with labels a and b")
    return 0


if __name__ == "__main__":
    sys.exit(main())
