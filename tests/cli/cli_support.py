"""Helpers shared by the CLI tests: a deepcanvas-server on a free loopback port."""
import re
import subprocess
import sys
import time


def start_server(server, args, log_path, env=None, listen="127.0.0.1:0", extra=()):
    """Starts `server serve --listen LISTEN ARGS EXTRA`, logging to log_path; returns the process
    and its URL prefix ws://127.0.0.1:PORT/. `server` may be a list (a command prefix such as
    `ip netns exec NS`, then the binary). Exits the test when it does not listen in 60 s."""
    command = list(server) if isinstance(server, (list, tuple)) else [server]
    with open(log_path, "w") as log:
        proc = subprocess.Popen(command + ["serve", "--listen", listen] + list(args) + list(extra),
                                stdout=log, stderr=subprocess.STDOUT, env=env)
    deadline = time.time() + 60
    while time.time() < deadline:
        if proc.poll() is not None:
            sys.exit("the server exited:\n" + open(log_path).read())
        m = re.search(r"event=listening .*port=(\d+)", open(log_path).read())
        if m:
            return proc, f"ws://127.0.0.1:{m.group(1)}/"
        time.sleep(0.05)
    proc.kill()
    sys.exit("the server did not start listening:\n" + open(log_path).read())


def stop_server(proc):
    proc.terminate()
    proc.wait(timeout=30)
