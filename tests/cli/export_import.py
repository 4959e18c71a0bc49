#!/usr/bin/env python3
"""Export, import, turntable and time-lapse through the real binaries.

Usage: export_import.py PATH/TO/deepcanvas-server PATH/TO/deepcanvas-client WORKDIR

A server (with a stroke log) gets the generated scene painted into canvas 'main'. Then:
- `deepcanvas-server export` of the stroke log writes a .vdb and a .glb;
- `deepcanvas-client import` of the .vdb into the empty canvas 'copy' renders like 'main' with
  the same camera (the mean pixel difference is small), and the .glb imports too;
- a corrupt file is refused (exit 1, the server's reason) and leaves 'copy' as it was;
- `render --turntable 4 --video` writes 4 frames (and the video where ffmpeg is installed), and
  `deepcanvas-server export --out x.png --turntable 3` the same through the client;
- `timelapse --generated --every 5` into the empty canvas 'tl' writes one frame per 5 strokes,
  the last like a render of 'tl' with its camera, and it refuses a canvas that holds paint.
Needs a Vulkan device (lavapipe will do).
"""
import os
import re
import shlex
import shutil
import struct
import subprocess
import sys
import time
import zlib


def run(args, what, rc=0):
    p = subprocess.run(args, capture_output=True, text=True, timeout=240)
    if p.returncode != rc:
        sys.exit(f"{what}: exit {p.returncode}, expected {rc}: {shlex.join(args)}\n"
                 f"--- stdout ---\n{p.stdout}--- stderr ---\n{p.stderr}")
    return p


def read_png(path):
    """(width, height, rows of RGBA bytes) of an 8-bit RGBA or RGB PNG."""
    data = open(path, "rb").read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", path
    pos, idat, w = 8, b"", 0
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, colour = struct.unpack(">IIBB", body[:10])
            assert depth == 8 and colour in (2, 6), (path, depth, colour)
            bpp = 4 if colour == 6 else 3
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = zlib.decompress(idat)
    stride = w * bpp
    rows, prev = [], bytearray(stride)
    for y in range(h):
        f = raw[y * (stride + 1)]
        line = bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for i in range(stride):
            a = line[i - bpp] if i >= bpp else 0
            b = prev[i]
            c = prev[i - bpp] if i >= bpp else 0
            if f == 1:
                line[i] = (line[i] + a) & 255
            elif f == 2:
                line[i] = (line[i] + b) & 255
            elif f == 3:
                line[i] = (line[i] + (a + b) // 2) & 255
            elif f == 4:
                pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                line[i] = (line[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
        rows.append(bytes(line))
        prev = line
    return w, h, bpp, rows


def mean_difference(a, b):
    wa, ha, bpp, ra = read_png(a)
    wb, hb, bppb, rb = read_png(b)
    assert (wa, ha, bpp) == (wb, hb, bppb), (a, b)
    total = 0
    for y in range(ha):
        for x in range(wa * bpp):
            if x % bpp != 3:
                total += abs(ra[y][x] - rb[y][x])
    return total / (wa * ha * 3)


def not_background(path):
    w, h, bpp, rows = read_png(path)
    return sum(1 for r in rows for x in range(0, w * bpp, bpp) if max(r[x:x + 3]) > 40)


def main():
    server, client, workdir = sys.argv[1:4]
    workdir = os.path.join(workdir, "export_import")
    shutil.rmtree(workdir, ignore_errors=True)
    os.makedirs(workdir)
    log_path = os.path.join(workdir, "server.log")
    strokes = os.path.join(workdir, "strokes.log")
    with open(log_path, "w") as log:
        proc = subprocess.Popen([server, "serve", "--in-memory", "--listen", "127.0.0.1:0",
                                 "--canvas", "main", "--canvas", "copy", "--canvas", "tl",
                                 "--stroke-log", strokes], stdout=log, stderr=subprocess.STDOUT)
    try:
        port = None
        deadline = time.time() + 60
        while port is None and time.time() < deadline:
            if proc.poll() is not None:
                sys.exit("the server exited:\n" + open(log_path).read())
            m = re.search(r"event=listening .*port=(\d+)", open(log_path).read())
            port = m.group(1) if m else None
            if port is None:
                time.sleep(0.05)
        if port is None:
            sys.exit("the server did not start listening:\n" + open(log_path).read())
        url = f"ws://127.0.0.1:{port}/"
        run([client, "paint", "--connect", url + "main", "--generated", "--quiet"], "paint")

        vdb, glb = os.path.join(workdir, "scene.vdb"), os.path.join(workdir, "scene.glb")
        strokes = strokes + ".main"  # one stroke log a canvas, named after it
        run([server, "export", strokes, "--out", vdb, "--voxel-size", "0.01", "--quiet"], "export vdb")
        p = run([server, "export", strokes, "--out", glb, "--quiet"], "export glb")
        if not re.search(r"wrote .*scene.glb: \d+ vertices, \d+ triangles", p.stdout):
            sys.exit("export glb: no summary line\n" + p.stdout)

        camera = None
        main_png = os.path.join(workdir, "main.png")
        p = run([client, "render", "--connect", url + "main", "--out", main_png, "--size", "320x200",
                 "--quiet"], "render main")
        camera = shlex.split(re.search(r"camera (--camera .*)", p.stderr).group(1))
        p = run([client, "import", vdb, "--connect", url + "copy", "--client-id", "importer",
                 "--quiet"], "import vdb")
        if not re.search(r"imported .*scene.vdb into canvas 'copy': \d+ cells as operation \d+",
                         p.stdout):
            sys.exit("import: no summary line\n" + p.stdout)
        copy_png = os.path.join(workdir, "copy.png")
        run([client, "render", "--connect", url + "copy", "--out", copy_png, "--size", "320x200",
             "--quiet"] + camera, "render copy")
        diff = mean_difference(main_png, copy_png)
        painted = not_background(main_png)
        print(f"imported copy vs painted canvas: mean difference {diff:.2f} of 255, "
              f"{painted} painted pixels")
        if painted < 500:
            sys.exit("the painted canvas renders almost empty")
        if diff > 6:
            sys.exit(f"the imported copy renders unlike the canvas (mean difference {diff:.2f})")

        junk = os.path.join(workdir, "junk.vdb")
        with open(junk, "wb") as f:
            f.write(os.urandom(3000))
        p = run([client, "import", junk, "--connect", url + "copy", "--quiet"], "import junk", rc=1)
        if "the server refused the import" not in p.stderr or "vdb" not in p.stderr:
            sys.exit("import junk: no reason given\n" + p.stderr)
        again_png = os.path.join(workdir, "copy_again.png")
        run([client, "render", "--connect", url + "copy", "--out", again_png, "--size", "320x200",
             "--quiet"] + camera, "render copy again")
        if open(again_png, "rb").read() != open(copy_png, "rb").read():
            sys.exit("a refused import changed the canvas")
        run([client, "import", glb, "--connect", url + "copy", "--at", "0.5,0,0", "--quiet"],
            "import glb")

        # A damaged .vdb that crashes OpenVDB's reader (found by flipping bytes with a fixed
        # seed, tried on the worker directly): the server converts imports in a child process,
        # so it answers malformed and goes on serving.
        import random
        good = open(vdb, "rb").read()
        worker = [server, "import-worker", "--format", "vdb", "--at", "0,0,0", "--scale", "1",
                  "--voxel-size", "0", "--colour", "1,1,1", "--density-scale", "1", "--roots", "4",
                  "--edge", "20000", "--max-depth", "24"]
        rng = random.Random(5)
        crasher = None
        for _ in range(60):
            b = bytearray(good)
            for _ in range(rng.randint(1, 4)):
                b[rng.randrange(len(b))] ^= rng.randint(1, 255)
            w = subprocess.run(worker, input=bytes(b), capture_output=True, timeout=120)
            # The worker exits 0 when it answers (also with an error); a crash is a signal, or
            # under a sanitizer its report and exit status 1.
            if w.returncode != 0:
                crasher = bytes(b)
                break
        if crasher is None:
            print("no flipped .vdb crashed the reader in 60 tries: the crash case is skipped")
        else:
            bad = os.path.join(workdir, "crasher.vdb")
            open(bad, "wb").write(crasher)
            p = run([client, "import", bad, "--connect", url + "copy", "--quiet"], "import crasher", rc=1)
            if "could not be read (the reader" not in p.stderr:
                sys.exit("import of a file that crashes the reader: no reason\n" + p.stderr)
            if proc.poll() is not None:
                sys.exit("the server died on a file that crashes the reader")
            run([client, "import", vdb, "--connect", url + "copy", "--at", "0,0.5,0", "--quiet"],
                "import after the crasher")
            print("a .vdb that crashes OpenVDB's reader: refused, the server goes on")

        spin = os.path.join(workdir, "spin.png")
        video = os.path.join(workdir, "spin.mp4")
        args = [client, "render", "--connect", url + "main", "--out", spin, "--size", "160x100",
                "--turntable", "4", "--quiet"]
        has_ffmpeg = shutil.which("ffmpeg") is not None
        if has_ffmpeg:
            args += ["--video", video]
        run(args, "turntable")
        frames = [os.path.join(workdir, f"spin_{i:04d}.png") for i in range(4)]
        for f in frames:
            if not os.path.exists(f) or not_background(f) < 50:
                sys.exit(f"turntable frame {f} missing or empty")
        if len({open(f, "rb").read() for f in frames}) != 4:
            sys.exit("turntable frames are not four different views")
        if has_ffmpeg and os.path.getsize(video) < 1000:
            sys.exit("turntable video missing")

        # The server's own PNG export: a turntable of the stroke log's canvas, rendered by the
        # client it finds beside it in the build tree.
        p = run([server, "export", strokes, "--out", os.path.join(workdir, "srv.png"),
                 "--turntable", "3", "--size", "160x100", "--quiet"], "export png")
        srv = [os.path.join(workdir, f"srv_{i:04d}.png") for i in range(3)]
        for f in srv:
            if not os.path.exists(f) or not_background(f) < 50:
                sys.exit(f"server turntable frame {f} missing or empty")
        if len({open(f, "rb").read() for f in srv}) != 3:
            sys.exit("server turntable frames are not three different views")

        tl = os.path.join(workdir, "tl.png")
        p = run([client, "timelapse", "--generated", "--connect", url + "tl", "--out", tl,
                 "--every", "5", "--size", "160x100", "--quiet"], "timelapse")
        m = re.search(r"wrote (\d+) time-lapse frames of (\d+) strokes", p.stdout)
        if not m:
            sys.exit("timelapse: no summary\n" + p.stdout)
        n, total = int(m.group(1)), int(m.group(2))
        if n != (total + 4) // 5:
            sys.exit(f"timelapse: {n} frames for {total} strokes every 5")
        first = not_background(os.path.join(workdir, "tl_0000.png"))
        last = not_background(os.path.join(workdir, f"tl_{n - 1:04d}.png"))
        print(f"time-lapse: {n} frames, painted pixels {first} in the first, {last} in the last")
        if not 0 < first < last:
            sys.exit("the time-lapse does not grow from the first frame to the last")
        run([client, "timelapse", "--generated", "--connect", url + "tl", "--out", tl, "--quiet"],
            "timelapse onto paint", rc=1)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    print("ok")


if __name__ == "__main__":
    main()
