#!/usr/bin/env python3
"""The docker images' start-up, checked without a Docker engine.

Usage: docker_images.py DOCKER_DIR SERVER [CLIENT]
  DOCKER_DIR  the repository's docker/ folder; SERVER, CLIENT  the built binaries.

  * docker/server-entrypoint.sh, the server image's entrypoint, run as the image runs it (the
    built server first on PATH) with a temporary tokens file named by DEEPCANVAS_TOKENS_FILE and
    DEEPCANVAS_LISTEN=0.0.0.0:0 (the image's address, on a free port): GET /healthz answers ok,
    a painter's token from the file gets a welcome and a wrong token `unauthorized`, and SIGTERM
    stops the server (the script execs it) with exit status 0;
  * without the tokens file (a missing path, and the default path when it does not exist here),
    or with a folder in its place, the script exits with status 2 and a message naming the path
    and how to mount the file, and starts no server;
  * the server Dockerfile copies that script and makes it the ENTRYPOINT;
  * every shared library the binaries link (ldd) belongs to a Debian package (dpkg -S) that the
    Dockerfile's runtime stage installs or that debian:12-slim holds, so the images can load.
Exit 0: pass; 1: fail; 77: skipped (python3-websockets, ldd or dpkg missing).
"""
import asyncio
import json
import os
import pathlib
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import urllib.request

try:
    import websockets
except ImportError:
    print("SKIP: python3 module 'websockets' is missing (Debian package python3-websockets)")
    sys.exit(77)

TOKENS = "# canvas role token\nart painter p-docker\nart viewer v-docker\n"
DEFAULT_TOKENS = "/run/deepcanvas/tokens"
# Packages every debian:12-slim image has (Priority: required, or needed by apt itself).
SLIM_BASE = {"libc6", "libgcc-s1", "libstdc++6", "zlib1g"}

failures = []


def fail(msg):
    print("FAIL:", msg)
    failures.append(msg)


def entrypoint_env(server, **extra):
    env = dict(os.environ)
    env.pop("DEEPCANVAS_TOKENS_FILE", None)
    env.pop("DEEPCANVAS_LISTEN", None)
    env.pop("DEEPCANVAS_DATA", None)
    env["PATH"] = str(pathlib.Path(server).resolve().parent) + os.pathsep + env.get("PATH", "")
    env.update(extra)
    return env


async def hello(port, token):
    async with websockets.connect(f"ws://127.0.0.1:{port}/", max_size=None) as ws:
        await ws.send(json.dumps({"type": "hello", "protocol_version": 1, "role": "painter",
                                  "token": token, "canvas": "art",
                                  "client_name": "docker-test"}))
        return json.loads(await asyncio.wait_for(ws.recv(), 30))


def check_start_with_tokens(script, server, tmp):
    tokens = pathlib.Path(tmp) / "tokens"
    tokens.write_text(TOKENS)
    env = entrypoint_env(server, DEEPCANVAS_TOKENS_FILE=str(tokens),
                         DEEPCANVAS_LISTEN="0.0.0.0:0",
                         DEEPCANVAS_DATA=str(pathlib.Path(tokens).parent / "data"))
    proc = subprocess.Popen(["sh", str(script)], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    log = []
    try:
        port = None
        for line in proc.stderr:
            log.append(line)
            if "event=listening" in line:
                port = int(line.split("port=")[1].split()[0])
                break
        if port is None:
            proc.wait(timeout=30)
            fail(f"entrypoint with tokens exited {proc.returncode} without listening:\n"
                 + "".join(log))
            return
        rest = []
        threading.Thread(target=lambda: rest.append(proc.stderr.read()), daemon=True).start()
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=30) as r:
            body = r.read().decode()
            if r.status != 200 or body.strip() != "ok":
                fail(f"/healthz answered {r.status} {body!r}")
        welcome = asyncio.run(hello(port, "p-docker"))
        if welcome.get("type") != "welcome":
            fail(f"the tokens file's painter token got {welcome}")
        refused = asyncio.run(hello(port, "not-in-the-file"))
        if refused.get("type") != "error" or refused.get("code") != "unauthorized":
            fail(f"a token not in the file got {refused}")
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    if proc.returncode != 0:
        fail(f"server exit status {proc.returncode} after SIGTERM (the script must exec it)")
    print("entrypoint with tokens: listening, /healthz ok, tokens from the file applied")


def check_refusal(script, server, tokens_path, want):
    extra = {} if tokens_path is None else {"DEEPCANVAS_TOKENS_FILE": tokens_path}
    r = subprocess.run(["sh", str(script)], env=entrypoint_env(server, **extra),
                       capture_output=True, text=True, timeout=60)
    shown = tokens_path or DEFAULT_TOKENS
    if r.returncode != 2:
        fail(f"entrypoint with tokens {shown}: exit status {r.returncode}, want 2")
    for text in want:
        if text not in r.stderr:
            fail(f"entrypoint with tokens {shown}: message lacks {text!r}: {r.stderr!r}")
    if "event=listening" in r.stderr:
        fail(f"entrypoint with tokens {shown}: a server started")
    print(f"entrypoint refuses {shown}: {r.stderr.splitlines()[0] if r.stderr else ''}")


def check_dockerfile_entrypoint(docker_dir):
    text = (docker_dir / "server.Dockerfile").read_text()
    copy = re.search(r"^COPY\s+docker/server-entrypoint\.sh\s+(\S+)\s*$", text, re.M)
    entry = re.search(r"^ENTRYPOINT\s+(\[.*\])\s*$", text, re.M)
    if not copy or not entry:
        fail("server.Dockerfile does not COPY docker/server-entrypoint.sh and set an ENTRYPOINT")
        return
    if json.loads(entry.group(1)) != [copy.group(1)]:
        fail(f"server.Dockerfile ENTRYPOINT {entry.group(1)} is not the copied script "
             f"{copy.group(1)}")
    if not os.access(docker_dir / "server-entrypoint.sh", os.X_OK):
        fail("docker/server-entrypoint.sh is not executable (COPY keeps the mode)")


def runtime_packages(dockerfile):
    """The packages apt-get installs in the Dockerfile's last stage."""
    text = dockerfile.read_text().replace("\\\n", " ")
    last_stage = text[text.rfind("\nFROM "):]
    pkgs = set()
    for m in re.finditer(r"apt-get install ([^&\n]*)", last_stage):
        pkgs |= {w for w in m.group(1).split() if not w.startswith("-")}
    return pkgs


def packages_of(libs):
    """{library path: Debian package} from one dpkg -S call (dpkg is slow to start). A library
    is looked up under its path, /usr + its path (merged /usr) and its real path."""
    candidates = {lib: [lib, "/usr" + lib, os.path.realpath(lib)] for lib in libs}
    paths = sorted({p for c in candidates.values() for p in c})
    r = subprocess.run(["dpkg", "-S"] + paths, capture_output=True, text=True)
    owner = {}
    for line in r.stdout.splitlines():
        pkg, _, path = line.partition(": ")
        owner[path.strip()] = pkg.split(",")[0].strip()
    return {lib: next((owner[p] for p in c if p in owner), None) for lib, c in candidates.items()}


def check_libraries(binary, dockerfile):
    listed = runtime_packages(dockerfile)
    failed_before = len(failures)
    if not os.access(binary, os.X_OK):
        fail(f"{binary} is missing: build it first")
        return
    ldd = subprocess.run(["ldd", binary], capture_output=True, text=True, check=True).stdout
    libs = re.findall(r"=>\s+(/\S+)", ldd)
    # A sanitizer build of the tests links the sanitizer runtimes; the images build in Release.
    libs = [l for l in libs if not re.search(r"/lib(asan|ubsan|tsan|lsan)\.so", l)]
    if not libs:
        fail(f"ldd {binary} listed no libraries")
    for lib, pkg in packages_of(libs).items():
        if pkg is None:
            fail(f"{binary}: {lib} belongs to no Debian package")
        elif pkg.split(":")[0] not in listed | SLIM_BASE:
            fail(f"{dockerfile.name}: {binary} links {lib} from {pkg}, which the runtime stage "
                 f"does not install (it installs {sorted(listed)})")
    if len(failures) == failed_before:
        print(f"{dockerfile.name}: {len(libs)} shared libraries, all from installed packages")


def main():
    if len(sys.argv) not in (3, 4):
        print(__doc__)
        return 2
    docker_dir, server = pathlib.Path(sys.argv[1]), sys.argv[2]
    client = sys.argv[3] if len(sys.argv) == 4 else None
    if not shutil.which("ldd") or not shutil.which("dpkg"):
        print("SKIP: ldd or dpkg is missing (the library check needs a Debian system)")
        return 77
    script = docker_dir / "server-entrypoint.sh"
    with tempfile.TemporaryDirectory() as tmp:
        check_start_with_tokens(script, server, tmp)
        missing = str(pathlib.Path(tmp) / "no-such-tokens")
        check_refusal(script, server, missing,
                      [f"no tokens file at {missing}", "docker run", "DEEPCANVAS_TOKENS_FILE"])
        if not os.path.exists(DEFAULT_TOKENS):
            check_refusal(script, server, None, [f"no tokens file at {DEFAULT_TOKENS}"])
        check_refusal(script, server, tmp, [f"tokens file {tmp} is not a readable file"])
    check_dockerfile_entrypoint(docker_dir)
    check_libraries(server, docker_dir / "server.Dockerfile")
    if client:
        check_libraries(client, docker_dir / "client.Dockerfile")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
