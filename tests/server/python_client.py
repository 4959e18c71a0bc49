#!/usr/bin/env python3
"""A third-party deepcanvas client written from protocol/PROTOCOL.md (python3-websockets); block
frames are decoded by the document's example client (protocol/examples/minimal_client.py).

Usage: python_client.py PATH/TO/deepcanvas-server

Starts `deepcanvas-server serve` on a free loopback port with a tokens file, then:
  * a painter connects (hello with "delta_frames": true -> welcome), receives the snapshot,
    paints a stroke, waits for the ack and for an epoch_end at or past the ack's epoch, decoding
    every block frame (header CRCs, zstd, delta + byte-plane transform, payload CRC) into its own
    replica, temporal delta frames (section 4.7) resolved against the blocks it holds;
  * the replica is checked: every cell reachable from the roots lies in received data and its
    children point back at it; the leaf under the stroke has the colour that pick_up reports;
  * a viewer joining late without delta frames gets a snapshot whose replica holds the same
    pools, and only full frames; a second stroke then reaches both replicas identically;
  * a viewer's stroke gets `unauthorized`, a wrong token a fatal `unauthorized`;
  * a painter with "block_frames": false gets its ack and stats and no block frame;
  * presence (section 3.9): a painter's reaches another painter and a viewer with its artist id
    and name, never itself; a viewer's is refused; a painter that leaves is gone for the others;
  * SIGTERM stops the server cleanly (exit code 0).
Exit 0: pass; 1: fail; 77: skipped (python3-websockets missing).
"""
import asyncio
import importlib.util
import json
import os
import pathlib
import signal
import subprocess
import sys
import tempfile
import zlib

try:
    import websockets
except ImportError:
    print("SKIP: python3 module 'websockets' is missing (Debian package python3-websockets)")
    sys.exit(77)

EDGE = 8.0
TOKENS = "# canvas role token\nart painter p-123\nart viewer v-456\n"


def load_example_client():
    """PROTOCOL.md's example client, whose block-frame decoder (sections 4.1 to 4.3) this test
    uses, so that the tree holds one Python decoder and this test exercises the documented one."""
    root = pathlib.Path(__file__).resolve().parents[2]
    path = root / "protocol" / "examples" / "minimal_client.py"
    spec = importlib.util.spec_from_file_location("minimal_client", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


example = load_example_client()
NONE = example.NONE
pack_pools = example.raw_payload  # the raw payload (section 4.2) of decoded pools


def decode_block(frame):
    """Returns (epoch, block, version, first, cells, pools, delta); delta = None for a full
    frame, else (base_version, payload_crc, changed) with the pools holding the changed cells'
    values alone and changed their indices (resolve_delta)."""
    try:
        f = example.decode_block(frame)
    except example.ProtocolError as e:
        raise AssertionError(f"block frame: {e}") from e
    delta = None if f["base"] is None else (f["base"], f["crc"], f["changed"])
    return f["epoch"], f["block"], f["version"], f["first"], f["cells"], f["pools"], delta


class Replica:
    """Pools as Python lists (section 4.4), applied per epoch (section 4.5)."""

    def __init__(self, roots_per_axis):
        self.n = roots_per_axis
        self.first_child, self.colour, self.group_parent, self.depth_flags = [], [], [], []
        self.pending = []
        self.epoch = None
        self.frames = 0
        self.deltas = 0
        self.held = {}  # block -> (version, first, cells) of the pools applied last

    def add_frame(self, frame):
        """Buffers a frame for the next epoch_end; a delta is resolved now (section 4.7)."""
        fepoch, block, bver, first, cells, pools, delta = decode_block(frame)
        if delta is not None:
            self.resolve_delta(block, bver, first, cells, pools, *delta)
            self.deltas += 1
        self.pending.append((fepoch, block, bver, first, cells, pools))

    def resolve_delta(self, block, bver, first, cells, pools, base_version, pcrc, changed):
        groups = cells // 8
        base = None
        for _e, b, v, f, c, p in reversed(self.pending):  # the newest staged version first
            if b == block and "first_child" in p:
                base = (v, f, c, p)
                break
        if base is None and block in self.held:
            v, f, c = self.held[block]
            base = (v, f, c, {"first_child": self.first_child[f:f + c],
                              "colour": self.colour[f:f + c],
                              "group_parent": self.group_parent[f // 8:(f + c) // 8],
                              "depth_flags": self.depth_flags[f // 8:(f + c) // 8]})
        # The base's range starts at `first` and may be shorter (the block grew): past its end
        # the base counts as 0.
        if base is None or base[0] != base_version or base[1] != first or base[2] > cells:
            raise AssertionError(f"delta for block {block} v{bver} needs base v{base_version}, "
                                 f"replica holds {base[:3] if base else None}")
        for name in ("first_child", "colour", "group_parent", "depth_flags"):
            if name in pools:
                b, per_cell = base[3][name], name in ("first_child", "colour")
                new = [b[i] if i < len(b) else 0 for i in range(cells if per_cell else groups)]
                for i, v in zip(changed["cells" if per_cell else "groups"], pools[name], strict=True):
                    new[i] = v
                pools[name] = new
        assert zlib.crc32(pack_pools(pools, cells, groups)) == pcrc, "bad delta payload crc"

    def apply_epoch(self, epoch):
        for fepoch, block, bver, first, cells, pools in self.pending:
            if fepoch > epoch:  # section 4.5: frames carry epochs <= their batch's
                raise AssertionError(f"frame of epoch {fepoch} in batch {epoch}")
            end = first + cells
            if len(self.first_child) < end:
                grow = end - len(self.first_child)
                self.first_child += [0] * grow
                self.colour += [0] * grow
                self.group_parent += [0] * (grow // 8)
                self.depth_flags += [0] * (grow // 8)
            if "first_child" in pools:
                self.first_child[first:end] = pools["first_child"]
            if "colour" in pools:
                self.colour[first:end] = pools["colour"]
            if "group_parent" in pools:
                self.group_parent[first // 8:end // 8] = pools["group_parent"]
            if "depth_flags" in pools:
                self.depth_flags[first // 8:end // 8] = pools["depth_flags"]
            if "first_child" in pools:
                self.held[block] = (bver, first, cells)
        self.frames += len(self.pending)
        self.pending.clear()
        self.epoch = epoch

    def check_reachable(self):
        cells = len(self.first_child)
        stack = list(range(self.n ** 3))
        assert cells >= len(stack), "roots missing"
        seen = 0
        while stack:
            c = stack.pop()
            seen += 1
            fc = self.first_child[c]
            if fc == NONE:
                continue
            assert fc % 8 == 0 and fc + 8 <= cells, f"cell {c} points outside received data"
            g = fc // 8
            assert not self.depth_flags[g] & 0x80, f"cell {c} points at a free group"
            assert self.group_parent[g] == c, f"group {g} does not point back at {c}"
            stack.extend(range(fc, fc + 8))
        return seen

    def leaf_at(self, p):
        root_edge = EDGE / self.n
        idx = [min(self.n - 1, int((p[a] + EDGE / 2) // root_edge)) for a in range(3)]
        c = idx[0] + self.n * (idx[1] + self.n * idx[2])
        lo = [-EDGE / 2 + idx[a] * root_edge for a in range(3)]
        e = root_edge
        while self.first_child[c] != NONE:
            e /= 2
            slot = 0
            for a in range(3):
                if p[a] >= lo[a] + e:
                    slot |= 1 << a
                    lo[a] += e
            c = self.first_child[c] + slot
        return c


async def recv_json(ws, replica=None):
    """Next control message; block frames on the way are buffered into `replica`."""
    while True:
        m = await asyncio.wait_for(ws.recv(), 30)
        if isinstance(m, bytes):
            if replica is not None:
                replica.add_frame(m)
            continue
        msg = json.loads(m)
        if msg["type"] == "epoch_end" and replica is not None:
            replica.apply_epoch(msg["epoch"])
        return msg


async def recv_control(ws, replica):
    """Next control message other than epoch_end (those are applied on the way)."""
    while True:
        msg = await recv_json(ws, replica)
        if msg["type"] != "epoch_end":
            return msg


async def settle(ws, replica):
    """Until the canvas stops changing: an ack names the epoch holding a stroke's paint, and the
    server may go on merging uniform cells back in later epochs (PROTOCOL.md, ack). Asks for
    stats until two answers 0.2 s apart name the same epoch and the replica has applied it."""
    last = None
    while True:
        await ws.send(json.dumps({"type": "stats_request"}))
        stats = await recv_control(ws, replica)
        assert stats["type"] == "stats", stats
        while replica.epoch < stats["epoch"]:
            await recv_json(ws, replica)
        if stats["epoch"] == last:
            return last
        last = stats["epoch"]
        await asyncio.sleep(0.2)


async def hello(port, role, token, delta_frames=False, block_frames=True, name="python-test"):
    ws = await websockets.connect(f"ws://127.0.0.1:{port}/", max_size=None)
    msg = {"type": "hello", "protocol_version": 1, "role": role, "token": token, "canvas": "art",
           "client_name": name}
    if delta_frames:
        msg["delta_frames"] = True
    if not block_frames:
        msg["block_frames"] = False
    await ws.send(json.dumps(msg))
    return ws, json.loads(await asyncio.wait_for(ws.recv(), 30))


async def paint_and_wait(ws, replica, handle, brush, samples):
    await ws.send(json.dumps({"type": "stroke", "handle": handle, "brush": brush,
                              "samples": samples}))
    acked = None
    while acked is None or replica.epoch is None or replica.epoch < acked:
        msg = await recv_json(ws, replica)
        assert msg["type"] in ("ack", "epoch_end"), msg
        if msg["type"] == "ack":
            assert msg["handle"] == handle and msg["stroke_id"] >= 1
            acked = msg["epoch"]
    return acked


async def run(port):
    ws, welcome = await hello(port, "painter", "p-123", delta_frames=True)
    assert welcome["type"] == "welcome", welcome
    assert welcome["geometry"]["edge_m"] == EDGE
    replica = Replica(welcome["geometry"]["roots_per_axis"])
    while replica.epoch is None:  # the snapshot
        await recv_json(ws, replica)
    red = {"mode": "paint", "colour": [1, 0, 0, 1], "opacity": 1, "hardness": 1}
    await paint_and_wait(ws, replica, 1, red, [[0.01, 0.01, 0.01, 0.2, 1, 0],
                                              [0.3, 0.01, 0.01, 0.2, 1, 16]])
    reachable = replica.check_reachable()
    assert reachable > 64, "the stroke refined nothing"
    await ws.send(json.dumps({"type": "pick_up", "request_id": 5, "position": [0.1, 0.01, 0.01]}))
    msg = await recv_control(ws, replica)
    assert msg["type"] == "pick_up_reply", msg
    # The reply reads the settled canvas (after the stroke's merges): compare with that state.
    await settle(ws, replica)
    leaf = replica.leaf_at((0.1, 0.01, 0.01))
    rgba = replica.colour[leaf]
    got = [round(c * 255) for c in msg["colour"]] + [round(msg["density"] * 255)]
    want = [rgba & 255, rgba >> 8 & 255, rgba >> 16 & 255, rgba >> 24]
    assert got == want, f"pick_up says {got}, replica leaf {leaf} holds {want}"
    assert want[0] > 200 and want[1] < 50, f"the stroke is not red in the replica: {want}"

    # A late viewer: its snapshot equals the painter's replica.
    vws, vwelcome = await hello(port, "viewer", "v-456")
    assert vwelcome["type"] == "welcome" and vwelcome["role"] == "viewer", vwelcome
    viewer = Replica(vwelcome["geometry"]["roots_per_axis"])
    while viewer.epoch is None:
        await recv_json(vws, viewer)
    epoch = await settle(ws, replica)
    while viewer.epoch < epoch:
        await recv_json(vws, viewer)
    assert viewer.first_child == replica.first_child and viewer.colour == replica.colour
    assert viewer.group_parent == replica.group_parent
    assert viewer.depth_flags == replica.depth_flags
    # A second stroke reaches both: the painter through deltas, the viewer through full frames.
    deltas_before = replica.deltas
    blue = {"mode": "paint", "colour": [0, 0, 1, 1], "opacity": 1, "hardness": 1}
    acked = await paint_and_wait(ws, replica, 2, blue, [[0.2, 0.3, 0.01, 0.15, 1, 0],
                                                        [0.2, 0.5, 0.01, 0.15, 1, 16]])
    epoch = await settle(ws, replica)
    assert epoch >= acked
    while viewer.epoch < epoch:
        await recv_json(vws, viewer)
    assert replica.deltas > deltas_before, "the painter asked for delta frames and got none"
    assert viewer.deltas == 0, "a client that did not ask for delta frames got some"
    assert viewer.first_child == replica.first_child and viewer.colour == replica.colour
    assert viewer.group_parent == replica.group_parent
    assert viewer.depth_flags == replica.depth_flags
    replica.check_reachable()
    # A viewer may not paint; the error names the stroke and does not close the connection.
    await vws.send(json.dumps({"type": "stroke", "handle": 9, "brush": red,
                               "samples": [[0, 0, 0, 0.1, 1, 0]]}))
    msg = await recv_control(vws, viewer)
    assert msg["type"] == "error" and msg["code"] == "unauthorized" and msg["handle"] == 9, msg
    assert not msg.get("fatal", False)
    await vws.send(json.dumps({"type": "stats_request"}))
    msg = await recv_control(vws, viewer)
    assert msg["type"] == "stats" and msg["strokes"] == 2, msg
    await vws.close()

    # A wrong token: a fatal error, then the server closes.
    bws, refused = await hello(port, "painter", "guess")
    assert refused["type"] == "error" and refused["code"] == "unauthorized" and refused.get("fatal")
    try:
        await asyncio.wait_for(bws.recv(), 10)
        raise AssertionError("the server kept a refused connection open")
    except websockets.exceptions.ConnectionClosed:
        pass
    # A painter that asked for no block frames: its stroke's ack and its stats come, and not a
    # single binary frame or epoch_end before them.
    pws, pwelcome = await hello(port, "painter", "p-123", block_frames=False)
    assert pwelcome["type"] == "welcome", pwelcome
    await pws.send(json.dumps({"type": "stroke", "handle": 3, "brush": blue,
                               "samples": [[0.4, 0.4, 0.01, 0.1, 1, 0]]}))
    await pws.send(json.dumps({"type": "stats_request"}))
    answers = {}
    while len(answers) < 2:  # the ack and the stats, in either order
        raw = await asyncio.wait_for(pws.recv(), 30)
        assert isinstance(raw, str), "a client without block frames got a binary frame"
        msg = json.loads(raw)
        assert msg["type"] in ("ack", "stats") and msg["type"] not in answers, msg
        answers[msg["type"]] = msg
    assert answers["ack"]["handle"] == 3, answers["ack"]
    assert answers["stats"]["blocks_sent"] == 0 and answers["stats"]["bytes_sent"] == 0, answers["stats"]
    await pws.close()
    await ws.close()
    await presence(port)
    print(f"python client: {replica.frames} frames ({replica.deltas} deltas), {reachable} "
          f"reachable cells, epoch {replica.epoch}, pick-up {got}; viewer {viewer.frames} frames")


async def presence(port):
    """Section 3.9, from the document: two painters and a viewer, none of them streaming."""
    a, _ = await hello(port, "painter", "p-123", block_frames=False, name="py-a")
    b, _ = await hello(port, "painter", "p-123", block_frames=False, name="py-b")
    v, _ = await hello(port, "viewer", "v-456", block_frames=False, name="py-v")
    mine = {"cursor_on_canvas": True, "cursor": [0.5, 1.5, -0.25], "eye": [0.0, 1.6, 5.0],
            "target": [0.0, 1.6, 0.0], "vfov_deg": 45.0, "colour": [1.0, 0.5, 0.0, 1.0],
            "size_m": 0.02, "mode": "paint", "painting": False}
    await a.send(json.dumps({"type": "presence", **mine}))
    artist = None
    for ws in (b, v):
        msg = json.loads(await asyncio.wait_for(ws.recv(), 30))
        assert msg["type"] == "presence" and msg["name"] == "py-a" and not msg["gone"], msg
        assert {k: msg[k] for k in mine} == mine, msg
        assert artist in (None, msg["artist"]), "two artist ids for one painter"
        artist = msg["artist"]
    # The painter itself is sent nothing of its own: its next message answers its request.
    await a.send(json.dumps({"type": "stats_request"}))
    msg = json.loads(await asyncio.wait_for(a.recv(), 30))
    assert msg["type"] == "stats", msg
    # A viewer has no presence to show.
    await v.send(json.dumps({"type": "presence", **mine}))
    msg = json.loads(await asyncio.wait_for(v.recv(), 30))
    assert msg["type"] == "error" and msg["code"] == "unauthorized", msg
    assert msg["in_reply_to"] == "presence" and not msg.get("fatal", False), msg
    # The painter leaves: gone, with its id and name and nothing else.
    await a.close()
    for ws in (b, v):
        msg = json.loads(await asyncio.wait_for(ws.recv(), 30))
        assert msg == {"type": "presence", "artist": artist, "name": "py-a", "gone": True}, msg
    await b.close()
    await v.close()


def main():
    server = sys.argv[1]
    with tempfile.NamedTemporaryFile("w", suffix=".tokens", delete=False) as f:
        f.write(TOKENS)
        tokens = f.name
    proc = subprocess.Popen([server, "serve", "--in-memory", "--listen", "127.0.0.1:0", "--tokens", tokens,
                             "--edge", str(EDGE), "--max-depth", "10"],
                            stderr=subprocess.PIPE, text=True)
    try:
        port = None
        for line in proc.stderr:
            sys.stderr.write(line)
            if "event=listening" in line:
                port = int(line.split("port=")[1].split()[0])
                break
        if port is None:
            print("FAIL: the server did not start")
            return 1
        asyncio.run(run(port))
        proc.send_signal(signal.SIGTERM)
        _, rest = proc.communicate(timeout=30)
        sys.stderr.write(rest)
        if proc.returncode != 0:
            print(f"FAIL: server exit code {proc.returncode} after SIGTERM")
            return 1
        if "event=stopped" not in rest:
            print("FAIL: no clean stop logged")
            return 1
        print("PASS")
        return 0
    except AssertionError as e:
        print(f"FAIL: {e}")
        return 1
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.unlink(tokens)


if __name__ == "__main__":
    sys.exit(main())
