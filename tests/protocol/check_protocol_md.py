"""Checks that protocol/PROTOCOL.md and its example client (protocol/examples/) hold.

usage:
  check_protocol_md.py lint PROTOCOL.md EXAMPLE.py [pool_layout.h]
      Every ```python block of the document is a verbatim excerpt of the example; every
      "section N" / "N.M" reference names a heading that exists; the document holds no
      measurements or development history. With pool_layout.h: the example's copies of the
      layout constants (NONE, DEPTH_MASK, FREE_GROUP, POOL_LAYOUT's version) equal the header's.
  check_protocol_md.py decode EXAMPLE.py DIR
      Decodes every DIR/*.frame with the example's decode_block() and writes DIR/<name>.json:
      {"epoch", "block", "version", "first", "cells", pools...} (protocol_md_test.cpp compares
      them with what the C++ encoder was given).
  check_protocol_md.py serve deepcanvas-server EXAMPLE.py [--runs N] [--seed S]
      Starts `deepcanvas-server serve` on a free loopback port (no tokens file), runs the example
      with --verify on the fresh canvas, paints a history of strokes, then runs the example N
      more times on the canvas with history: with and without delta frames, each while another
      painter paints elsewhere and while the canvas is otherwise idle. Stops the server with
      SIGTERM.
Exit status 0: pass; 1: fail; 77: skipped (python3-websockets, or any zstd decompressor,
missing).
"""
import asyncio
import importlib.util
import json
import pathlib
import random
import re
import shutil
import signal
import subprocess
import sys
import threading


def load_example(path):
    spec = importlib.util.spec_from_file_location("minimal_client", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# ---- lint ------------------------------------------------------------------------------------

def layout_constant_failures(example_path, layout_path):
    """The example client cannot include pool_layout.h, so it copies the constants a client
    needs; this keeps the copies from drifting from the one definition."""
    header = pathlib.Path(layout_path).read_text()
    constant = r"DC_CONST\s+uint\s+(k\w+)\s*=\s*(0[xX][0-9a-fA-F]+|\d+)u\s*;"
    defined = {m.group(1): int(m.group(2), 0) for m in re.finditer(constant, header)}
    example = load_example(example_path)
    copies = {"kNoCell": example.NONE, "kDepthMask": example.DEPTH_MASK,
              "kGroupFreeFlag": example.FREE_GROUP, "kLayoutVersion": example.POOL_LAYOUT["version"]}
    failures = []
    for name, value in copies.items():
        if name not in defined:
            failures.append(f"{layout_path} defines no {name}")
        elif defined[name] != value:
            failures.append(f"{example_path}: {name} is {value:#x}, {layout_path} says "
                            f"{defined[name]:#x}")
    return failures


def lint(doc_path, example_path, layout_path=None):
    doc = pathlib.Path(doc_path).read_text()
    example = pathlib.Path(example_path).read_text()
    failures = layout_constant_failures(example_path, layout_path) if layout_path else []
    blocks = re.findall(r"```python\n(.*?)```", doc, re.S)
    if not blocks:
        failures.append("no python excerpt of the example in the document")
    for b in blocks:
        if b not in example:
            first = b.strip().splitlines()[0] if b.strip() else ""
            failures.append(f"python block starting {first!r} is not an excerpt of {example_path}")
    headings = set()
    for m in re.finditer(r"^#{2,4} (\d+(?:\.\d+)?)\.? ", doc, re.M):
        headings.add(m.group(1))
    refs = re.findall(r"\bsections? (\d+(?:\.\d+)?)", doc)
    refs += re.findall(r"\((\d\.\d+)[),;]", doc)
    refs += re.findall(r"\b(?:and|or|see|in|of) (\d\.\d+)\b", doc)
    for r in sorted(set(refs)):
        if r not in headings:
            failures.append(f"reference to section {r}, which does not exist")
    for pattern in (r"\bsession \d", r"tried and" + r" not kept", r"\bMB/s\b", r"\bmedian",
                    r"\bmeasured\b", r"\bbenchmark"):
        for m in re.finditer(pattern, doc, re.I):
            line = doc.count("\n", 0, m.start()) + 1
            failures.append(f"line {line}: {m.group(0)!r}: measurements and history belong "
                            "elsewhere (docs/)")
    for f in failures:
        print(f"FAIL: {f}")
    if not failures:
        print(f"PASS: {len(blocks)} excerpts, {len(set(refs))} section references")
    return 1 if failures else 0


# ---- decode ----------------------------------------------------------------------------------

def decode(example_path, frames_dir):
    decode_block = load_example(example_path).decode_block
    for frame in sorted(pathlib.Path(frames_dir).glob("*.frame")):
        f = decode_block(frame.read_bytes())
        out = {"epoch": f["epoch"], "block": f["block"], "version": f["version"],
               "first": f["first"], "cells": f["cells"]}
        for k, v in f["pools"].items():
            out[k] = list(v)
        frame.with_suffix(".json").write_text(json.dumps(out))
    return 0


# ---- serve -----------------------------------------------------------------------------------

async def paint_strokes(url, strokes, spread, centre, rng, pause_s=0.0):
    """A painter that asks for no canvas stream: paints `strokes` strokes of assorted brushes
    around `centre` and returns once every one is acked."""
    import websockets
    async with websockets.connect(url, max_size=None) as ws:
        await ws.send(json.dumps({"type": "hello", "protocol_version": 1, "role": "painter",
                                  "token": "history", "canvas": "default",
                                  "client_name": "history", "block_frames": False}))
        welcome = json.loads(await asyncio.wait_for(ws.recv(), 30))
        assert welcome["type"] == "welcome", welcome
        modes = ["paint", "paint", "paint", "erase", "recolor", "smudge"]
        for h in range(strokes):
            brush = {"mode": rng.choice(modes),
                     "colour": [rng.random(), rng.random(), rng.random(), rng.uniform(0.3, 1)],
                     "opacity": rng.uniform(0.5, 1), "hardness": rng.random()}
            a = [c + rng.uniform(-spread, spread) for c in centre]
            b = [c + rng.uniform(-spread / 4, spread / 4) for c in a]
            r = rng.uniform(0.02, 0.15)
            samples = [[*(a[k] + (b[k] - a[k]) * i / 4 for k in range(3)), r, 1, 16 * i]
                       for i in range(5)]
            await ws.send(json.dumps({"type": "stroke", "handle": h, "brush": brush,
                                      "samples": samples}))
            if pause_s:
                await asyncio.sleep(pause_s)
        acked = 0
        while acked < strokes:
            msg = json.loads(await asyncio.wait_for(ws.recv(), 60))
            assert msg["type"] == "ack", msg
            acked += 1


async def run_example(example, url, seed, delta, painter_rng=None):
    cmd = [sys.executable, example, "--url", url, "--verify", "--seed", str(seed)]
    if not delta:
        cmd.append("--no-delta")
    proc = await asyncio.create_subprocess_exec(*cmd, stdout=subprocess.PIPE,
                                                stderr=subprocess.STDOUT)
    painter = None
    if painter_rng is not None:  # another painter, away from the example's strokes
        painter = asyncio.create_task(
            paint_strokes(url, 20, 0.5, (2.5, 2.5, 2.5), painter_rng, pause_s=0.03))
    out, _ = await asyncio.wait_for(proc.communicate(), 300)
    if painter is not None:
        await painter
    return proc.returncode, out.decode(), " ".join(cmd[1:])


def serve(server, example, runs, seed):
    try:
        import websockets  # noqa: F401
    except ImportError:
        print("SKIP: python3 module 'websockets' is missing (Debian package python3-websockets)")
        return 77
    try:
        import zstandard  # noqa: F401
    except ImportError:
        if not shutil.which("zstd"):
            print("SKIP: no zstd decompressor: neither the python3 module 'zstandard' (Debian "
                  "package python3-zstandard) nor the zstd command (Debian package zstd)")
            return 77
    proc = subprocess.Popen([server, "serve", "--in-memory", "--listen", "127.0.0.1:0", "--edge", "8",
                             "--max-depth", "10"], stderr=subprocess.PIPE, text=True)
    log = []
    try:
        port = None
        for line in proc.stderr:
            log.append(line)
            if "event=listening" in line:
                port = int(line.split("port=")[1].split()[0])
                break
        if port is None:
            print("FAIL: the server did not start\n" + "".join(log))
            return 1
        # Keep reading the server's log so that it never blocks on a full pipe.
        drain = threading.Thread(target=lambda: log.extend(proc.stderr), daemon=True)
        drain.start()
        url = f"ws://127.0.0.1:{port}/"
        rng = random.Random(seed)
        # (delta frames, another painter) cycles through all four combinations.
        combos = [(True, False), (False, True), (True, True), (False, False)]
        plan = [("fresh canvas", True, False)]
        plan += [(f"with history {i + 1}", *combos[i % 4]) for i in range(runs)]
        failed = 0
        for i, (what, delta, concurrent) in enumerate(plan):
            if i == 1:
                asyncio.run(paint_strokes(url, 40, 1.0, (0, 0, 0), rng))
            label = what + (", delta frames" if delta else ", full frames") + \
                (", another painter painting" if concurrent else "")
            rc, out, cmd = asyncio.run(run_example(
                example, url, seed * 1000 + i, delta,
                random.Random(rng.random()) if concurrent else None))
            print(f"--- run {i}: {label}: exit {rc}\n{out}", end="")
            if rc != 0:
                print(f"FAIL: {cmd}")
                failed += 1
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
        drain.join(timeout=5)
        if proc.returncode != 0 or not any("event=stopped" in line for line in log):
            print(f"FAIL: server exit code {proc.returncode} after SIGTERM\n" + "".join(log[-20:]))
            return 1
        if failed:
            print(f"FAIL: {failed} of {len(plan)} runs")
            return 1
        print(f"PASS: {len(plan)} runs")
        return 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def main(argv):
    if len(argv) in (3, 4) and argv[0] == "lint":
        return lint(*argv[1:])
    if len(argv) >= 3 and argv[0] == "decode":
        return decode(argv[1], argv[2])
    if len(argv) >= 3 and argv[0] == "serve":
        opts = dict(zip(argv[3::2], argv[4::2]))
        return serve(argv[1], argv[2], int(opts.get("--runs", 6)), int(opts.get("--seed", 1)))
    print(__doc__)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
