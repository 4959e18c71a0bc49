#!/usr/bin/env python3
"""render prints the camera it chose; pasted back, that camera renders the same image.

Usage: render_camera.py PATH/TO/deepcanvas-server PATH/TO/deepcanvas-client WORKDIR

Starts `deepcanvas-server serve` on a free loopback port, paints the generated scene into it,
renders it with the default camera (framed on the content), takes the `--camera ... --up ...`
line render writes on stderr, renders again with exactly those arguments and compares the two
PNG files byte for byte: the printed camera is the one used, and --camera's default up (+y)
agrees with the framing's. Along the way: paint and render show progress on stderr, and
--quiet hides it. Needs a Vulkan device (lavapipe will do).
"""
import os
import re
import shlex
import subprocess
import sys
import time


def run(args, what):
    p = subprocess.run(args, capture_output=True, text=True, timeout=240)
    if p.returncode != 0:
        sys.exit(f"{what} failed ({p.returncode}): {shlex.join(args)}\n"
                 f"--- stdout ---\n{p.stdout}--- stderr ---\n{p.stderr}")
    return p


def expect(cond, message, p):
    if not cond:
        sys.exit(f"{message}\n--- stdout ---\n{p.stdout}--- stderr ---\n{p.stderr}")


def main():
    server, client, workdir = sys.argv[1:4]
    os.makedirs(workdir, exist_ok=True)
    log_path = os.path.join(workdir, "render_camera_server.log")
    with open(log_path, "w") as log:
        proc = subprocess.Popen([server, "serve", "--in-memory", "--listen", "127.0.0.1:0", "--canvas", "main"],
                                stdout=log, stderr=subprocess.STDOUT)
    try:
        port = None
        deadline = time.time() + 60
        while port is None and time.time() < deadline:
            if proc.poll() is not None:
                sys.exit("the server exited:\n" + open(log_path).read())
            m = re.search(r"event=listening .*port=(\d+)", open(log_path).read())
            if m:
                port = m.group(1)
            else:
                time.sleep(0.05)
        if port is None:
            sys.exit("the server did not start listening:\n" + open(log_path).read())
        url = f"ws://127.0.0.1:{port}/main"

        p = run([client, "paint", "--connect", url, "--generated"], "paint")
        expect(re.search(r"paint generated scene: (\d+)/\1 strokes", p.stderr),
               "paint: no progress line on stderr", p)
        p = run([client, "paint", "--connect", url, "--generated", "--quiet"], "paint --quiet")
        expect("strokes in" not in p.stderr, "paint --quiet: progress on stderr", p)

        first = os.path.join(workdir, "render_camera_default.png")
        again = os.path.join(workdir, "render_camera_pasted.png")
        p = run([client, "render", "--connect", url, "--size", "96x54", "--out", first], "render")
        expect("catching up with canvas 'main'" in p.stderr, "render: no catch-up progress", p)
        m = re.search(r"^deepcanvas-client render: camera (--camera \S+ --up \+y)$", p.stderr,
                      re.MULTILINE)
        expect(m, "render: no camera line on stderr", p)
        pasted = m.group(1).split()
        p = run([client, "render", "--connect", url, "--size", "96x54", "--out", again,
                 "--quiet"] + pasted, "render with the printed camera")
        expect("catching up" not in p.stderr, "render --quiet: progress on stderr", p)
        with open(first, "rb") as a, open(again, "rb") as b:
            same = a.read() == b.read()
        expect(same, f"{first} and {again} differ: the printed camera is not the one used "
               f"({' '.join(pasted)})", p)
        print(f"ok: {' '.join(pasted)} renders the same image")
    finally:
        proc.terminate()
        proc.wait(timeout=30)


if __name__ == "__main__":
    main()
