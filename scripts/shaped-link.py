#!/usr/bin/env python3
"""A real network link with a home or mobile connection's rate, delay and loss, between two
network namespaces, for trying a server and its clients as remote artists meet them.

Usage (as root):
  shaped-link.py --name dc --rate-mbit 50 --rtt-ms 40 --loss 0.005

Makes the namespaces NAME-s (the server side, address 10.77.0.1) and NAME-c (the client side,
10.77.0.2), joined only by this link, prints one line `ready server=10.77.0.1 client=10.77.0.2`,
and forwards packets until SIGTERM or SIGINT. Then it removes both namespaces and prints one
line of JSON with what it did (packets and bytes each way, packets lost at random, packets
dropped because the queue was full).

Run programs on either side with `ip netns exec NAME-s ...` and `ip netns exec NAME-c ...`.
Traffic never leaves the two namespaces.

How: each namespace gets a TUN device; this process is the wire between them. Every IP packet
is lost with probability --loss, else queued behind the packets before it at --rate-mbit (a
queue of at most --queue-ms of sending time; a packet that would wait longer is dropped, as a
router drops), then delivered --rtt-ms/2 after it left. Both directions alike, each on its own.
The kernel's netem qdisc does the same, but it is not built into every kernel (containers and
micro-VMs often lack it), and this needs nothing but /dev/net/tun and iproute2.
"""
import argparse
import collections
import fcntl
import json
import os
import random
import select
import signal
import struct
import subprocess
import sys
import time

TUNSETIFF = 0x400454CA
IFF_TUN = 0x0001
IFF_NO_PI = 0x1000
SERVER_ADDR, CLIENT_ADDR = "10.77.0.1", "10.77.0.2"


def ip(*args):
    p = subprocess.run(["ip", *args], capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {p.stderr.strip()}")


def open_tun(name):
    fd = os.open("/dev/net/tun", os.O_RDWR | os.O_NONBLOCK)
    fcntl.ioctl(fd, TUNSETIFF, struct.pack("16sH", name.encode(), IFF_TUN | IFF_NO_PI))
    return fd


class Direction:
    """One way of the link: a queue of (deliver_at, packet) in sending order."""

    def __init__(self, args, rng):
        self.rate = args.rate_mbit * 1e6 / 8  # bytes per second
        self.delay = args.rtt_ms / 2000.0
        self.loss = args.loss
        self.queue_s = args.queue_ms / 1000.0
        self.rng = rng
        self.busy_until = 0.0  # when the last queued packet has been sent
        self.queue = collections.deque()
        self.stats = {"packets": 0, "bytes": 0, "lost": 0, "queue_drops": 0}

    def offer(self, packet, now):
        if self.rng.random() < self.loss:
            self.stats["lost"] += 1
            return
        start = max(now, self.busy_until)
        if start - now > self.queue_s:
            self.stats["queue_drops"] += 1
            return
        self.busy_until = start + len(packet) / self.rate
        self.queue.append((self.busy_until + self.delay, packet))

    def deliver(self, fd, now):
        while self.queue and self.queue[0][0] <= now:
            _, packet = self.queue.popleft()
            try:
                os.write(fd, packet)
            except BlockingIOError:
                pass  # the receiving side's queue is full: the packet is lost there
            self.stats["packets"] += 1
            self.stats["bytes"] += len(packet)

    def next_due(self):
        return self.queue[0][0] if self.queue else None


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__.split("\n\n", 1)[1])
    ap.add_argument("--name", default="dc", help="namespace prefix (default dc: dc-s and dc-c)")
    ap.add_argument("--rate-mbit", type=float, default=50, help="link rate each way (default 50)")
    ap.add_argument("--rtt-ms", type=float, default=40, help="round-trip delay (default 40)")
    ap.add_argument("--loss", type=float, default=0.005,
                    help="probability a packet is lost, each way (default 0.005)")
    ap.add_argument("--queue-ms", type=float, default=200,
                    help="longest wait in the link's queue before a drop (default 200)")
    ap.add_argument("--seed", type=int, default=1, help="seed of the losses (default 1)")
    args = ap.parse_args()
    if not 0 <= args.loss < 1 or args.rate_mbit <= 0 or args.rtt_ms < 0 or args.queue_ms <= 0:
        ap.error("need --rate-mbit > 0, --rtt-ms >= 0, 0 <= --loss < 1 and --queue-ms > 0")
    if len(args.name) > 10 or not args.name.replace("-", "").isalnum():
        ap.error("--name: at most 10 letters, digits or dashes")
    if os.geteuid() != 0:
        sys.exit("shaped-link: needs root (network namespaces and TUN devices)")

    ns_s, ns_c = args.name + "-s", args.name + "-c"
    tun_s, tun_c = args.name + "-ts", args.name + "-tc"
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    made = []
    try:
        for ns in (ns_s, ns_c):
            ip("netns", "add", ns)
            made.append(ns)
            ip("-n", ns, "link", "set", "lo", "up")
        fd_s, fd_c = open_tun(tun_s), open_tun(tun_c)
        for tun, ns, addr, peer in ((tun_s, ns_s, SERVER_ADDR, CLIENT_ADDR),
                                    (tun_c, ns_c, CLIENT_ADDR, SERVER_ADDR)):
            ip("link", "set", tun, "netns", ns)
            ip("-n", ns, "link", "set", tun, "mtu", "1500")
            ip("-n", ns, "addr", "add", addr, "peer", peer, "dev", tun)
            ip("-n", ns, "link", "set", tun, "up")
    except (RuntimeError, OSError) as e:
        for ns in made:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        print(f"shaped-link: cannot make the link: {e}", file=sys.stderr)
        sys.exit(3)

    rng = random.Random(args.seed)
    to_client, to_server = Direction(args, rng), Direction(args, rng)
    print(f"ready server={SERVER_ADDR} client={CLIENT_ADDR} namespaces={ns_s},{ns_c}", flush=True)
    try:
        while not stop:
            now = time.monotonic()
            dues = [d for d in (to_client.next_due(), to_server.next_due()) if d is not None]
            timeout = max(0.0, min(dues) - now) if dues else 0.5
            try:
                readable, _, _ = select.select([fd_s, fd_c], [], [], min(timeout, 0.5))
            except InterruptedError:
                continue
            now = time.monotonic()
            for fd, way in ((fd_s, to_client), (fd_c, to_server)):
                if fd in readable:
                    while True:
                        try:
                            packet = os.read(fd, 65536)
                        except BlockingIOError:
                            break
                        way.offer(packet, now)
            to_client.deliver(fd_c, now)
            to_server.deliver(fd_s, now)
    finally:
        os.close(fd_s)
        os.close(fd_c)
        for ns in (ns_s, ns_c):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
    print(json.dumps({"to_client": to_client.stats, "to_server": to_server.stats}), flush=True)


if __name__ == "__main__":
    main()
