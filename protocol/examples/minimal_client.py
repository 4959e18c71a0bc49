#!/usr/bin/env python3
"""A deepcanvas client written from protocol/PROTOCOL.md (section 7 of it points here).

Joins a canvas, keeps a replica of the server's pools (block frames decoded and applied per
epoch, temporal delta frames resolved, neighbour links computed from the masks), paints one
stroke, waits until the replica shows it, and asks the server for the colour under it.

    python3 minimal_client.py [--url ws://127.0.0.1:7878/] [--canvas default] [--token -]

Needs python3 and the `websockets` module (Debian: python3-websockets); compressed frames are
decompressed with the `zstandard` module when it is installed (Debian: python3-zstandard), else
with the `zstd` command. --verify adds the checks the test suite runs (tests/protocol): the
replica's tree, its links against a brute-force neighbour search, and stats.live_cells once the
canvas is idle. Exit status 0: done; 1: a protocol violation or a failed check (the message
says which); 2: bad arguments.
"""
import argparse
import asyncio
import json
import math
import random
import struct
import subprocess
import sys
import zlib

# The pool layout's constants (section 4.4; shaders/include/pool_layout.h defines them, and
# tests/protocol/check_protocol_md.py checks these copies against it).
POOL_LAYOUT = {"id": "deepcanvas-soa-g8", "version": 1}  # kLayoutVersion
NONE = 0xFFFFFFFF  # kNoCell: "no cell" in first_child, group_parent and the links
DEPTH_MASK = 0x1F  # kDepthMask: depth_flags bits 0-4, the depth
FREE_GROUP = 0x80  # kGroupFreeFlag: depth_flags bit 7, a free group
HDR = struct.Struct("<4sHHHHIQQIIIIIIII")  # the 64-byte header of section 4.1


class ProtocolError(Exception):
    """The server broke the contract: close the connection (code 1002) and reconnect."""


# ---- block frames (sections 4.1 to 4.3) --------------------------------------------------------

def decompress(body, raw_size):
    try:
        import zstandard
        return zstandard.ZstdDecompressor().decompress(body, max_output_size=raw_size)
    except ImportError:
        return subprocess.run(["zstd", "-d", "-c"], input=body, capture_output=True,
                              check=True).stdout


def zigzag(r):   return ((r << 1) ^ (0xFFFFFFFF if r & 0x80000000 else 0)) & 0xFFFFFFFF
def unzigzag(f): return ((f >> 1) ^ (-(f & 1) & 0xFFFFFFFF)) & 0xFFFFFFFF


def undelta(codes, stride):  # the first_child / group_parent transform, inverted
    out, pred = [], 0
    for t in codes:
        if t == 0:
            out.append(NONE); continue
        k = zigzag((NONE - pred) & 0xFFFFFFFF)
        f = t - 1 if t <= k else t
        v = (pred + unzigzag(f)) & 0xFFFFFFFF
        out.append(v); pred = (v + stride) & 0xFFFFFFFF
    return out


def unplane(b, n):  # byte planes -> u32 list
    return [b[i] | b[n+i] << 8 | b[2*n+i] << 16 | b[3*n+i] << 24 for i in range(n)]


def raw_payload(pools, cells, groups):  # section 4.2, what payload_crc covers
    return b"".join([
        struct.pack(f"<{cells}I", *pools["first_child"]) if "first_child" in pools else b"",
        struct.pack(f"<{cells}I", *pools["colour"]) if "colour" in pools else b"",
        struct.pack(f"<{groups}I", *pools["group_parent"]) if "group_parent" in pools else b"",
        bytes(pools.get("depth_flags", [])), pools.get("mask", b"")])


def decode_block(frame):
    """One block frame -> dict(epoch, block, version, first, cells, base, crc, pools, changed).
    base is None for a full frame; for a delta frame (4.7) it is the base version, the pools
    hold the changed cells' values alone and changed their bitmaps (Replica.resolve_delta
    finishes them)."""
    (magic, ver, hsize, flags, fields, block, bver, epoch, first, cells,
     stored, raw, pcrc, scrc, base_distance, hcrc) = HDR.unpack_from(frame)
    if magic != b"DCBK" or ver != 2 or hsize != 64:
        raise ProtocolError("not a version-2 block frame")
    if zlib.crc32(frame[:60]) != hcrc or len(frame) - 64 != stored:
        raise ProtocolError("bad header_crc or stored_size")
    if bool(flags & 4) != (base_distance != 0):
        raise ProtocolError("bad delta flag / base_distance")
    body = frame[64:]
    if zlib.crc32(body) != scrc:
        raise ProtocolError("bad stored_crc")
    if flags & 1:
        body = decompress(body, raw)
    if len(body) != raw:
        raise ProtocolError("bad raw_size")
    groups, pos, pools, t = cells // 8, 0, {}, flags & 2
    def take(n):
        nonlocal pos; pos += n; return body[pos - n:pos]
    changed, n_cells, n_groups = {}, cells, groups  # a delta's bitmaps, and how many values follow
    if flags & 4:
        def bitmap(n):
            b = take((n + 7) // 8)
            return [i for i in range(n) if b[i // 8] >> (i % 8) & 1]
        if fields & 3:
            changed["cells"] = bitmap(cells); n_cells = len(changed["cells"])
        if fields & 12:
            changed["groups"] = bitmap(groups); n_groups = len(changed["groups"])
    if fields & 1:
        b = take(4 * n_cells)
        pools["first_child"] = (undelta(unplane(b, n_cells), 8) if t
                                else list(struct.unpack(f"<{n_cells}I", b)))
    if fields & 2:
        b = take(4 * n_cells)
        pools["colour"] = ([b[3*i] | b[3*i+1] << 8 | b[3*i+2] << 16 | b[3*n_cells+i] << 24
                            for i in range(n_cells)] if t
                           else list(struct.unpack(f"<{n_cells}I", b)))
    if fields & 4:
        b = take(4 * n_groups)
        pools["group_parent"] = (undelta(unplane(b, n_groups), 1) if t
                                 else list(struct.unpack(f"<{n_groups}I", b)))
    if fields & 8:
        pools["depth_flags"] = list(take(n_groups))
    if fields & 16:
        pools["mask"] = take((groups + 7) // 8)
    if pos != raw:
        raise ProtocolError("raw_size does not match the frame's fields")
    base = bver - base_distance if flags & 4 else None
    if base is None and zlib.crc32(raw_payload(pools, cells, groups)) != pcrc:
        raise ProtocolError("bad payload_crc")
    return {"epoch": epoch, "block": block, "version": bver, "first": first, "cells": cells,
            "base": base, "crc": pcrc, "pools": pools, "changed": changed}


# ---- the replica (sections 4.4 to 4.11) --------------------------------------------------------

POOLS = ("first_child", "colour", "group_parent", "depth_flags")


class Replica:
    def __init__(self, welcome):
        g = welcome["geometry"]
        self.n, self.edge = g["roots_per_axis"], g["edge_m"]
        self.block_cells = welcome["block_cells"]
        self.roots = self.n ** 3
        self.first_child, self.colour = [], []              # per cell
        self.group_parent, self.depth_flags = [], []        # per group
        self.links = []                                     # per group, 6 faces (G3, 4.9)
        self.held = {}      # block -> (version, first, cells) of the pools applied last
        self.batch = []     # the open batch: decoded (and resolved) frames, in arrival order
        self.epoch = None   # the last applied epoch_end
        self.frames = self.deltas = self.older = 0

    def add_frame(self, data):
        f = decode_block(data)
        if f["base"] is not None:
            self.resolve_delta(f)
            self.deltas += 1
        self.batch.append(f)

    def resolve_delta(self, f):
        """4.7: the base is the block as this client holds it at this point of the stream: its
        newest frame with pools in the open batch, else what the replica applied last."""
        base = next((b for b in reversed(self.batch)
                     if b["block"] == f["block"] and "first_child" in b["pools"]), None)
        if base is not None:
            version, first, cells, pools = (base[k] for k in ("version", "first", "cells", "pools"))
        elif f["block"] in self.held:
            version, first, cells = self.held[f["block"]]
            pools = {"first_child": self.first_child[first:first + cells],
                     "colour": self.colour[first:first + cells],
                     "group_parent": self.group_parent[first // 8:(first + cells) // 8],
                     "depth_flags": self.depth_flags[first // 8:(first + cells) // 8]}
        else:
            raise ProtocolError(f"delta for block {f['block']} but no version of it is held")
        if version != f["base"] or first != f["first"] or cells > f["cells"]:
            raise ProtocolError(f"delta for block {f['block']} needs base v{f['base']}, "
                                f"held: v{version} cells {first}+{cells}")
        for name in POOLS:  # the changed values over the base's; 0 past the end of its range
            if name in f["pools"]:
                b, per_cell = pools[name], name in ("first_child", "colour")
                n = f["cells"] if per_cell else f["cells"] // 8
                new = [b[i] if i < len(b) else 0 for i in range(n)]
                for i, v in zip(f["changed"]["cells" if per_cell else "groups"], f["pools"][name]):
                    new[i] = v
                f["pools"][name] = new
        if zlib.crc32(raw_payload(f["pools"], f["cells"], f["cells"] // 8)) != f["crc"]:
            raise ProtocolError("bad payload_crc after resolving a delta")

    def end_epoch(self, msg):
        """epoch_end: apply the whole batch at once, then recompute the masked groups' links."""
        e = msg["epoch"]
        if self.epoch is not None and e <= self.epoch:
            raise ProtocolError(f"epoch_end {e} after epoch_end {self.epoch}")
        if msg["blocks"] != len(self.batch):
            raise ProtocolError(f"epoch_end says {msg['blocks']} frames, {len(self.batch)} came")
        masked = set()
        for f in self.batch:
            if f["epoch"] > e:  # a frame may be older than its batch (4.5), never newer
                raise ProtocolError(f"frame of epoch {f['epoch']} in the batch of epoch {e}")
            self.older += f["epoch"] < e
            first, cells, p = f["first"], f["cells"], f["pools"]
            end, g0 = first + cells, first // 8
            if first // self.block_cells != f["block"] or \
                    first % self.block_cells + cells > self.block_cells:
                raise ProtocolError("frame range outside its block")
            if len(self.first_child) < end:  # the high-water mark moved up
                grow = end - len(self.first_child)
                self.first_child += [NONE] * grow; self.colour += [0] * grow
                self.group_parent += [NONE] * (grow // 8)
                self.depth_flags += [FREE_GROUP] * (grow // 8)
                self.links += [NONE] * (6 * (grow // 8))
            if "first_child" in p: self.first_child[first:end] = p["first_child"]
            if "colour" in p: self.colour[first:end] = p["colour"]
            if "group_parent" in p: self.group_parent[g0:end // 8] = p["group_parent"]
            if "depth_flags" in p: self.depth_flags[g0:end // 8] = p["depth_flags"]
            if "first_child" in p:
                self.held[f["block"]] = (f["version"], first, cells)
            for i, byte in enumerate(p.get("mask", b"")):  # masks are OR-ed
                for bit in range(8):
                    if byte >> bit & 1:
                        masked.add(g0 + 8 * i + bit)
        # Links: parents' groups first (a group's links read those of its parent's group).
        for g in sorted(masked, key=lambda g: self.depth_flags[g] & DEPTH_MASK):
            self.links[6 * g:6 * g + 6] = self.group_links(g)
        self.frames += len(self.batch)
        self.batch.clear()
        self.epoch = e

    # ---- neighbours (4.9) ----
    def root_neighbour(self, r, face):
        n, axis = self.n, face >> 1
        v = [r % n, r // n % n, r // (n * n)]
        v[axis] += 1 if face & 1 else -1
        return v[0] + n * (v[1] + n * v[2]) if 0 <= v[axis] < n else NONE

    def neighbour(self, c, face):
        """The face neighbour of cell c at its own depth, or the coarser leaf there; NONE at
        the canvas boundary. For a cell with children (a group's parent) it is always the
        same-depth cell (2:1 balance)."""
        axis = face >> 1
        if c < self.roots:
            return self.root_neighbour(c, face)
        if (c >> axis & 1) != (face & 1):          # inner face: the sibling
            return c ^ (1 << axis)
        q = self.links[6 * (c >> 3) + face]        # outer face: G3, the group's link
        if q == NONE or self.first_child[q] == NONE:
            return q
        return self.first_child[q] + ((c & 7) ^ (1 << axis))

    def group_links(self, g):
        if g < self.roots // 8 or self.depth_flags[g] & FREE_GROUP:
            return [NONE] * 6                      # root groups and free groups
        return [self.neighbour(self.group_parent[g], f) for f in range(6)]

    # ---- positions (4.10) ----
    def locate(self, p):
        """The leaf containing point p (metres) and its depth, by the rule pick_up uses."""
        n, h = self.n, self.edge / 2
        scale, top = float(n << 24) / self.edge, (n << 24) - 1
        u = [min(max(math.floor((v + h) * scale), 0), top) for v in p]
        c, d = (u[0] >> 24) + n * ((u[1] >> 24) + n * (u[2] >> 24)), 0
        while self.first_child[c] != NONE:
            d += 1
            s = 24 - d
            c = self.first_child[c] + (u[0] >> s & 1 | (u[1] >> s & 1) << 1 | (u[2] >> s & 1) << 2)
        return c, d

    # ---- checks (--verify) ----
    def coord(self, c):
        """(depth, x, y, z) of cell c in cells of its depth from the canvas's minimum corner."""
        d, x, y, z, bit = self.depth_flags[c >> 3] & DEPTH_MASK, 0, 0, 0, 0
        while c >= self.roots:
            x |= (c & 1) << bit; y |= (c >> 1 & 1) << bit; z |= (c >> 2 & 1) << bit
            bit += 1
            c = self.group_parent[c >> 3]
        n = self.n
        return d, x | (c % n) << bit, y | (c // n % n) << bit, z | (c // (n * n)) << bit

    def find(self, d, x, y, z):
        """The cell at depth d and (x, y, z), or the leaf above it; NONE outside the canvas."""
        if not all(0 <= v < self.n << d for v in (x, y, z)):
            return NONE
        c = (x >> d) + self.n * ((y >> d) + self.n * (z >> d))
        for k in range(d - 1, -1, -1):
            if self.first_child[c] == NONE:
                break
            c = self.first_child[c] + ((x >> k & 1) | (y >> k & 1) << 1 | (z >> k & 1) << 2)
        return c

    def check(self):
        """Every cell reachable from the roots lies in received data, its children point back
        at it with the right depth, and every live group is reachable; the links equal a
        brute-force neighbour search. Returns the live cell count."""
        reachable, stack = 0, list(range(self.roots))
        while stack:
            c = stack.pop()
            reachable += 1
            fc = self.first_child[c]
            if fc == NONE:
                continue
            g = fc >> 3
            assert fc % 8 == 0 and fc + 8 <= len(self.first_child), f"cell {c}: first_child {fc}"
            assert not self.depth_flags[g] & FREE_GROUP, f"cell {c} points at free group {g}"
            assert self.group_parent[g] == c, f"group {g} does not point back at {c}"
            depth = self.depth_flags[c >> 3] & DEPTH_MASK
            assert self.depth_flags[g] == depth + 1, f"group {g} depth"
            stack.extend(range(fc, fc + 8))
        live = 8 * sum(1 for df in self.depth_flags if not df & FREE_GROUP)
        assert reachable == live, f"{reachable} cells reachable, {live} live"
        steps = [(-1, 0, 0), (1, 0, 0), (0, -1, 0), (0, 1, 0), (0, 0, -1), (0, 0, 1)]
        for g in range(self.roots // 8, len(self.depth_flags)):
            if self.depth_flags[g] & FREE_GROUP:
                continue
            d, x, y, z = self.coord(self.group_parent[g])
            for f, (dx, dy, dz) in enumerate(steps):
                want = self.find(d, x + dx, y + dy, z + dz)
                assert self.links[6 * g + f] == want, \
                    f"group {g} face {f}: link {self.links[6 * g + f]}, neighbour {want}"
        return live


# ---- the conversation (sections 2, 3 and 4.5) --------------------------------------------------

class Connection:
    def __init__(self, ws, replica, timeout):
        self.ws, self.replica, self.timeout = ws, replica, timeout
        self.acks, self.replies = {}, []

    async def step(self):
        """Reads one message: block frames go into the open batch, epoch_end applies it, acks
        are recorded, other control messages are queued in self.replies."""
        m = await asyncio.wait_for(self.ws.recv(), self.timeout)
        if isinstance(m, bytes):
            self.replica.add_frame(m)
            return
        msg = json.loads(m)
        if msg["type"] == "epoch_end":
            self.replica.end_epoch(msg)
        elif msg["type"] == "ack":
            self.acks[msg["handle"]] = msg
        elif msg["type"] == "error" and msg.get("fatal"):
            raise ProtocolError(f"fatal error {msg['code']}: {msg['message']}")
        else:
            self.replies.append(msg)

    async def reply(self, type_):
        while True:
            for i, msg in enumerate(self.replies):
                if msg["type"] in (type_, "error"):
                    del self.replies[i]
                    if msg["type"] == "error":
                        raise ProtocolError(f"error {msg['code']}: {msg['message']}")
                    return msg
            await self.step()

    async def paint(self, handle, brush, samples):
        """Sends a stroke; returns once the replica shows it: an epoch_end with an epoch >= the
        ack's has been applied. That epoch_end may come before the ack or after it (3.4)."""
        await self.ws.send(json.dumps({"type": "stroke", "handle": handle, "brush": brush,
                                       "samples": samples}))
        while handle not in self.acks:
            await self.step()
            for msg in self.replies:
                if msg["type"] == "error" and msg.get("handle") == handle:
                    raise ProtocolError(f"stroke refused: {msg['code']}: {msg['message']}")
        ack = self.acks[handle]
        self.ack_came_first = self.replica.epoch < ack["epoch"]
        while self.replica.epoch < ack["epoch"]:
            await self.step()
        return ack

    async def settle(self, quiet_s=0.3, limit_s=60):
        """Until the canvas is idle: stats names the same epoch twice, quiet_s apart, and the
        replica has applied it. Returns that stats message."""
        last, loop = None, asyncio.get_running_loop()
        deadline = loop.time() + limit_s
        while loop.time() < deadline:
            await self.ws.send(json.dumps({"type": "stats_request"}))
            stats = await self.reply("stats")
            while self.replica.epoch < stats["epoch"]:
                await self.step()
            if last is not None and stats["epoch"] == last["epoch"] and \
                    stats["live_cells"] == last["live_cells"]:
                return stats
            last = stats
            await asyncio.sleep(quiet_s)
        raise ProtocolError(f"the canvas did not settle within {limit_s} s")


def quantise(v):
    """A colour channel (0..1, as the server stores it: single precision) -> its byte."""
    y = float(struct.unpack("<f", struct.pack("<f", v))[0]) * 255.0
    return int(y) + (1 if y - int(y) >= 0.5 else 0)


async def run(args):
    import websockets
    async with websockets.connect(args.url, max_size=None) as ws:
        hello = {"type": "hello", "protocol_version": 1, "role": "painter", "token": args.token,
                 "canvas": args.canvas, "client_name": "minimal_client.py",
                 "delta_frames": not args.no_delta}
        await ws.send(json.dumps(hello))
        welcome = json.loads(await asyncio.wait_for(ws.recv(), args.timeout))
        if welcome["type"] == "error":
            raise ProtocolError(f"refused: {welcome['code']}: {welcome['message']}")
        if welcome["protocol_version"] != 1 or \
                welcome["pool_layout"] != POOL_LAYOUT:
            raise ProtocolError("a protocol version or pool layout this client does not know")
        replica = Replica(welcome)
        conn = Connection(ws, replica, args.timeout)
        while replica.epoch is None:  # the snapshot: the first batch
            await conn.step()
        if replica.epoch < welcome["epoch"]:
            raise ProtocolError("the snapshot is older than welcome.epoch")
        snapshot = (replica.epoch, replica.frames, len(replica.first_child))

        # One stroke of opaque, hard paint near the canvas centre, scaled to the canvas.
        rng = random.Random(args.seed)
        size = min(welcome["geometry"]["edge_m"] / 16, 1.0)
        at = [rng.uniform(-size, size) for _ in range(3)]
        radius = max(size / 8, welcome["limits"]["min_radius_m"] * 2)
        rgb = [rng.choice((0.0, 0.2, 0.4, 0.6, 0.8, 1.0)) for _ in range(3)]
        brush = {"mode": "paint", "colour": rgb + [1.0], "opacity": 1.0, "hardness": 1.0}
        samples = [[at[0] - radius, at[1], at[2], radius, 1, 0],
                   [at[0] + radius, at[1], at[2], radius, 1, 16]]
        ack = await conn.paint(1, brush, samples)

        # The replica shows the stroke: the leaf at its centre holds the brush's bytes.
        want = [quantise(c) for c in rgb] + [255]
        leaf, depth = replica.locate(at)
        v = replica.colour[leaf]
        have = [v & 255, v >> 8 & 255, v >> 16 & 255, v >> 24]
        assert have == want, f"replica leaf {leaf} at {at} holds {have}, the brush is {want}"

        # pick_up: the server's leaf under the same point, once every earlier stroke completed.
        await ws.send(json.dumps({"type": "pick_up", "request_id": 7, "position": at}))
        pick = await conn.reply("pick_up_reply")
        got = [round(c * 255) for c in pick["colour"]] + [round(pick["density"] * 255)]
        assert got == want, f"pick_up says {got}, the brush is {want}"

        print(f"joined at epoch {snapshot[0]} ({snapshot[1]} frames, {snapshot[2]} cells); "
              f"stroke {ack['stroke_id']} acked in epoch {ack['epoch']} "
              f"({'before' if conn.ack_came_first else 'after'} its epoch_end); "
              f"leaf {leaf} at depth {depth} = {have}, pick_up depth {pick['depth']}")
        if args.verify:
            replica.check()
            stats = await conn.settle()
            live = replica.check()
            assert stats["live_cells"] == live, \
                f"stats: {stats['live_cells']} live cells, the replica {live}"
            print(f"verified at epoch {replica.epoch}: {live} live cells, links of "
                  f"{len(replica.depth_flags)} groups, {replica.frames} frames "
                  f"({replica.deltas} deltas, {replica.older} older than their batch)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--url", default="ws://127.0.0.1:7878/")
    ap.add_argument("--canvas", default="default", help="canvas name (default: default)")
    ap.add_argument("--token", default="-",
                    help="painter token; a server without --tokens accepts any valid one")
    ap.add_argument("--no-delta", action="store_true", help="ask for full frames only")
    ap.add_argument("--seed", type=int, default=None, help="stroke position and colour")
    ap.add_argument("--timeout", type=float, default=30.0, help="seconds per message")
    ap.add_argument("--verify", action="store_true", help="the test suite's extra checks")
    args = ap.parse_args()
    try:
        import websockets
    except ImportError:
        print("minimal_client.py: the python3 module 'websockets' is missing "
              "(Debian: python3-websockets)", file=sys.stderr)
        return 1
    try:
        asyncio.run(run(args))
    except (ProtocolError, AssertionError, asyncio.TimeoutError, OSError,
            websockets.exceptions.WebSocketException) as e:
        print(f"minimal_client.py: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
