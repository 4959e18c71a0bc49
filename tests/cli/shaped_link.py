#!/usr/bin/env python3
"""A painter and a viewer reach the server over a shaped link (scripts/shaped-link.py: 50 Mbit/s,
40 ms round trip, 0.5% of packets lost each way), in network namespaces the test makes itself.

Usage: shaped_link.py PATH/TO/deepcanvas-server PATH/TO/deepcanvas-client PATH/TO/shaped-link.py WORKDIR

The server listens on the link's server side with tokens; the painter paints demo.apa (from
$DEEPCANVAS_PAINTINGS; else the generated scene) from the client side (every stroke acked); a viewer there renders it; the same view rendered on
the server's side of the link gives the same PNG byte for byte, so nothing was lost on the way.
The link's own count shows packets really were lost and resent. Exit 77 (skipped) where network
namespaces or TUN devices cannot be made (not root, no /dev/net/tun, no iproute2).
"""
import json
import os
import re
import shutil
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from cli_support import start_server, stop_server  # noqa: E402


def skip(why):
    print(f"skipped: {why}")
    sys.exit(77)


def run(args, what):
    p = subprocess.run(args, capture_output=True, text=True, timeout=240)
    if p.returncode != 0:
        sys.exit(f"{what} failed ({p.returncode}): {' '.join(args)}\n{p.stdout}\n{p.stderr}")
    return p


def main():
    server, client, link_script, workdir = sys.argv[1:5]
    if os.geteuid() != 0:
        skip("needs root for network namespaces")
    if not os.path.exists("/dev/net/tun") or shutil.which("ip") is None:
        skip("needs /dev/net/tun and iproute2's ip")
    os.makedirs(workdir, exist_ok=True)
    name = f"dct{os.getpid() % 100000}"
    link = subprocess.Popen([sys.executable, link_script, "--name", name, "--rate-mbit", "50",
                             "--rtt-ms", "40", "--loss", "0.005"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready = link.stdout.readline()
    if not ready.startswith("ready"):
        err = link.stderr.read()
        link.wait()
        skip(f"the link could not be made: {err.strip() or ready.strip()}")
    in_server = ["ip", "netns", "exec", f"{name}-s"]
    in_client = ["ip", "netns", "exec", f"{name}-c"]
    proc = None
    try:
        tokens = os.path.join(workdir, "shaped_link_tokens")
        with open(tokens, "w") as f:
            f.write("main painter p-shaped\nmain viewer v-shaped\n")
        proc, _ = start_server(in_server + [server], [], os.path.join(workdir, "shaped_link_server.log"),
                               listen="10.77.0.1:0",
                               extra=["--in-memory", "--tokens", tokens])
        port = re.search(r"event=listening .*port=(\d+)",
                         open(os.path.join(workdir, "shaped_link_server.log")).read()).group(1)
        url = f"ws://10.77.0.1:{port}/main"

        demo = os.path.join(os.environ.get("DEEPCANVAS_PAINTINGS", ""), "demo.apa")
        what = [demo] if os.path.exists(demo) else ["--generated"]
        t0 = time.time()
        p = run(in_client + [client, "paint", "--connect", url, "--token", "p-shaped"] + what,
                "paint over the link")
        m = re.search(r"paint [^:]*: (\d+)/\1 strokes", p.stderr)
        if not m:
            sys.exit("paint: not every stroke was acked\n" + p.stderr)
        paint_s = time.time() - t0

        over_link = os.path.join(workdir, "shaped_link_client.png")
        at_server = os.path.join(workdir, "shaped_link_server.png")
        t0 = time.time()
        p = run(in_client + [client, "render", "--connect", url, "--token", "v-shaped",
                             "--size", "160x90", "--out", over_link], "render over the link")
        join_s = time.time() - t0
        cam = re.search(r"^deepcanvas-client render: camera (--camera \S+ --up \+y)$", p.stderr,
                        re.MULTILINE)
        if not cam:
            sys.exit("render: no camera line\n" + p.stderr)
        run(in_server + [client, "render", "--connect", url, "--token", "v-shaped", "--size",
                         "160x90", "--out", at_server, "--quiet"] + cam.group(1).split(),
            "render on the server's side")
        with open(over_link, "rb") as a, open(at_server, "rb") as b:
            if a.read() != b.read():
                sys.exit(f"{over_link} and {at_server} differ: the replica over the link is not "
                         "the server's canvas")
    finally:
        if proc is not None:
            stop_server(proc)
        link.terminate()
        out, err = link.communicate(timeout=30)
    stats = json.loads(out.strip().splitlines()[-1])
    print(f"ok: {m.group(1)} strokes painted in {paint_s:.1f} s, a viewer joined and rendered in "
          f"{join_s:.1f} s over the link; link: {json.dumps(stats)}")
    down = stats["to_client"]
    if down["bytes"] < 100_000:
        sys.exit("the link carried almost nothing: the traffic went another way")
    if down["lost"] + stats["to_server"]["lost"] == 0:
        sys.exit("no packet was lost: the link's loss did not apply")


if __name__ == "__main__":
    main()
