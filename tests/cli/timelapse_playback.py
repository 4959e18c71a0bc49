#!/usr/bin/env python3
"""A time-lapse of a data directory's history through the real binaries.

Usage: timelapse_playback.py PATH/TO/deepcanvas-server PATH/TO/deepcanvas-client WORKDIR

A server with a data directory gets the generated scene painted into canvas 'art', and the
painter undoes its last two strokes. While it keeps serving, `serve --playback DIR/art` plays the
history back:
- `timelapse --playback --every 4` writes one frame per 4 operations (strokes and undos), and
  its last frame, rendered with the same camera, is the live canvas's render;
- a second time-lapse of the same playback is refused (it goes forward only);
- `--every-seconds` steps by the history's wall clock on a new playback server;
- a canvas that is not a playback, and a SOURCE that does not exist, are refused with a reason.
Needs a Vulkan device (lavapipe will do).
"""
import math
import os
import re
import shlex
import shutil
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from cli_support import start_server as start, stop_server as stop  # noqa: E402
from export_import import mean_difference, not_background, run  # noqa: E402


def main():
    server, client, workdir = sys.argv[1:4]
    workdir = os.path.join(workdir, "timelapse_playback")
    shutil.rmtree(workdir, ignore_errors=True)
    os.makedirs(workdir)
    data = os.path.join(workdir, "data")
    live, url = start(server, ["--data", data, "--canvas", "art"], os.path.join(workdir, "live.log"))
    servers = [live]
    try:
        p = run([client, "paint", "--connect", url + "art", "--generated", "--client-id", "artist",
                 "--quiet"], "paint")
        run([client, "paint", "--connect", url + "art", "--client-id", "artist", "--undo-last", "2",
             "--quiet"], "undo")
        art_png = os.path.join(workdir, "art.png")
        p = run([client, "render", "--connect", url + "art", "--out", art_png, "--size", "160x100",
                 "--quiet"], "render art")
        camera = shlex.split(re.search(r"camera (--camera .*)", p.stderr).group(1))

        play, play_url = start(server, ["--playback", os.path.join(data, "art")],
                               os.path.join(workdir, "playback.log"))
        servers.append(play)
        frames = os.path.join(workdir, "tl.png")
        p = run([client, "timelapse", "--playback", "--connect", play_url + "art", "--out", frames,
                 "--every", "4", "--size", "160x100", "--quiet"] + camera, "timelapse --playback")
        m = re.search(r"wrote (\d+) time-lapse frames of (\d+) strokes", p.stdout)
        if not m:
            sys.exit("timelapse --playback: no summary\n" + p.stdout)
        n, ops = int(m.group(1)), int(m.group(2))
        if n != math.ceil(ops / 4):
            sys.exit(f"timelapse --playback: {n} frames for {ops} operations every 4")
        first = not_background(os.path.join(workdir, "tl_0000.png"))
        last_png = os.path.join(workdir, f"tl_{n - 1:04d}.png")
        diff = mean_difference(last_png, art_png)
        print(f"playback time-lapse: {n} frames of {ops} operations; painted pixels "
              f"{first} in the first; last frame vs the live canvas: mean difference {diff:.3f}")
        if first <= 0 or not_background(art_png) < 200:
            sys.exit("the time-lapse or the live canvas renders empty")
        if diff > 0.5:
            sys.exit(f"the history played back is not the live canvas (mean difference {diff:.2f})")
        p = run([client, "timelapse", "--playback", "--connect", play_url + "art", "--out", frames,
                 "--quiet"], "a second time-lapse of the same playback", rc=1)
        if "already stands at event" not in p.stderr:
            sys.exit("a stepped playback: no reason given\n" + p.stderr)

        timed, timed_url = start(server, ["--playback", os.path.join(data, "art")],
                                 os.path.join(workdir, "timed.log"))
        servers.append(timed)
        p = run([client, "timelapse", "--playback", "--connect", timed_url + "art", "--out",
                 os.path.join(workdir, "sec.png"), "--every-seconds", "0.1", "--size", "80x50",
                 "--quiet"], "timelapse --every-seconds")
        m = re.search(r"wrote (\d+) time-lapse frames", p.stdout)
        if not m or int(m.group(1)) < 2:
            sys.exit("timelapse --every-seconds: fewer than 2 frames\n" + p.stdout)
        print(f"--every-seconds 0.1: {m.group(1)} frames")

        p = run([client, "timelapse", "--playback", "--connect", url + "art", "--out", frames,
                 "--quiet"], "timelapse --playback of a live canvas", rc=1)
        if "does not play back a history" not in p.stderr:
            sys.exit("a live canvas stepped as a playback: no reason given\n" + p.stderr)
        p = run([server, "serve", "--playback", os.path.join(workdir, "missing"), "--listen",
                 "127.0.0.1:0"], "serve --playback of a missing file", rc=1)
        if "--playback:" not in p.stderr:
            sys.exit("serve --playback of a missing file: no reason given\n" + p.stderr)
    finally:
        for s in servers:
            stop(s)
    print("ok")


if __name__ == "__main__":
    main()
