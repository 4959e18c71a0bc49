#!/usr/bin/env python3
"""The headset client as a real OpenXR application, against a headless OpenXR runtime.

Usage: xr_headset.py PATH/TO/deepcanvas-server PATH/TO/deepcanvas-client RUNTIME.tar.gz WORKDIR
                    [PATH/TO/shaped-link.py]

The runtime is Monado's null compositor and simulated HMD (../shared/tools/openxr; its README):
no display, no controllers, frames paced at 20 Hz. A server gets the generated scene; then
`deepcanvas-client xr --frames 60 --pose-trace T` must
- submit 60 rendered frames (stereo projection layers) and end the session cleanly;
- read both eyes' poses from the runtime and use them: their separation is the simulated HMD's
  63 mm, and 63 mm x the artist's world scale in the canvas;
- paint the trace's scripted controller stroke (the runtime has no controllers), which the
  server acks and counts;
and without a runtime the command fails saying there is none. With shaped-link.py, as root where
network namespaces and TUN devices can be made: the headset joins the same scene over a 1 Mbit/s,
80 ms link and must show it (its first picture, part of the snapshot) well before the whole has
arrived, its frame loop running meanwhile (a progressive join, not a wait for the whole canvas).
Exit 77 (skipped) when the runtime archive is not there.
"""
import json
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
import urllib.request

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from cli_support import start_server, stop_server  # noqa: E402


def progressive_join_over_a_thin_link(server, client, link_script, workdir, env):
    """The headset joins the generated scene over 1 Mbit/s, 80 ms: the first picture comes at
    least a second before the whole snapshot has arrived (or the whole is still on its way when
    the 20 rendered frames are done)."""
    if os.geteuid() != 0 or not os.path.exists("/dev/net/tun") or shutil.which("ip") is None:
        print("thin link: skipped (needs root, /dev/net/tun and iproute2 for network namespaces)")
        return
    name = f"dcx{os.getpid() % 100000}"
    link = subprocess.Popen([sys.executable, link_script, "--name", name, "--rate-mbit", "1",
                             "--rtt-ms", "80"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready = link.stdout.readline()
    if not ready.startswith("ready"):
        err = link.stderr.read()
        link.wait()
        print(f"thin link: skipped (the link could not be made: {err.strip() or ready.strip()})")
        return
    in_server = ["ip", "netns", "exec", f"{name}-s"]
    in_client = ["ip", "netns", "exec", f"{name}-c"]
    proc = None
    try:
        tokens = os.path.join(workdir, "thin_link_tokens")
        with open(tokens, "w") as f:
            f.write("default painter p-thin\n")
        log = os.path.join(workdir, "thin_link_server.log")
        proc, _ = start_server(in_server + [server], [], log, listen="10.77.0.1:0",
                               extra=["--in-memory", "--tokens", tokens])
        port = re.search(r"event=listening .*port=(\d+)", open(log).read()).group(1)
        url = f"ws://10.77.0.1:{port}/default"
        subprocess.run(in_server + [client, "paint", "--connect", url, "--token", "p-thin",
                                    "--generated", "--quiet"],
                       check=True, capture_output=True, timeout=240)
        t0 = time.time()
        p = subprocess.run(in_client + [client, "xr", "--connect", url, "--token", "p-thin",
                                        "--frames", "20", "--timeout", "60", "--json", "--quiet"],
                           env=env, capture_output=True, text=True, timeout=240)
        if p.returncode != 0:
            sys.exit(f"xr over the thin link: exit {p.returncode}\n{p.stdout}{p.stderr[-4000:]}")
        r = json.loads(p.stdout.strip().splitlines()[-1])
        print("xr over 1 Mbit/s, 80 ms:", json.dumps(r), f"({time.time() - t0:.1f} s in all)")
        if r["frames_rendered"] < 20:
            sys.exit("over the thin link: fewer than 20 frames rendered")
        first, whole = r["first_picture_s"], r["whole_canvas_s"]
        if not first > 0:
            sys.exit("over the thin link: no first picture")
        if whole is not None and whole < first + 1.0:
            sys.exit(f"over the thin link the first picture came at {first} s, the whole canvas at "
                     f"{whole} s: the headset waited for (nearly) the whole snapshot")
    finally:
        if proc:
            stop_server(proc)
        link.terminate()
        link.wait(timeout=30)


def main():
    server, client, runtime_tgz, workdir = sys.argv[1:5]
    link_script = sys.argv[5] if len(sys.argv) > 5 else None
    if not os.path.exists(runtime_tgz):
        print(f"no OpenXR runtime archive at {runtime_tgz}: skipped")
        sys.exit(77)
    workdir = os.path.join(workdir, "xr_headset")
    shutil.rmtree(workdir, ignore_errors=True)
    os.makedirs(workdir)
    with tarfile.open(runtime_tgz) as t:
        t.extractall(workdir)
    rt = os.path.join(workdir, "monado-null-runtime")
    env = dict(os.environ)
    env["XR_RUNTIME_JSON"] = os.path.join(rt, "share/openxr/1/openxr_monado.json")
    env["XRT_COMPOSITOR_NULL"] = "1"
    env.setdefault("VK_DRIVER_FILES", "/usr/share/vulkan/icd.d/lvp_icd.x86_64.json")
    env.setdefault("VK_ICD_FILENAMES", env["VK_DRIVER_FILES"])
    env["XRT_COMPOSITOR_LOG"] = "warn"
    env["PROBER_LOG"] = "warn"
    env["XDG_CONFIG_HOME"] = tempfile.mkdtemp(dir=workdir)
    # Under ASan: the loader's and the runtime's own leaks are not ours (see the file).
    supp = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "sanitizers",
                        "lsan_openxr.supp")
    env["LSAN_OPTIONS"] = (env.get("LSAN_OPTIONS", "") + ":suppressions=" + supp).lstrip(":")

    proc, base_url = start_server(server, ["--in-memory"], os.path.join(workdir, "server.log"))
    try:
        port = re.search(r":(\d+)/$", base_url).group(1)
        url = f"ws://127.0.0.1:{port}/default"

        def strokes():
            text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10).read().decode()
            return int(re.search(r'^deepcanvas_strokes_total\{canvas="default"\} (\d+)', text, re.M).group(1))

        subprocess.run([client, "paint", "--connect", url, "--generated", "--quiet"], check=True,
                       capture_output=True, timeout=240)
        before = strokes()
        trace = os.path.join(workdir, "head.trace")
        subprocess.run([client, "pose-trace", "--box", "-1,0,-1,1,2,1", "--seconds", "20", "--out",
                        trace], check=True, capture_output=True, timeout=60)
        p = subprocess.run([client, "xr", "--connect", url, "--frames", "60", "--pose-trace", trace,
                            "--json", "--quiet"], env=env, capture_output=True, text=True, timeout=240)
        if p.returncode != 0:
            sys.exit(f"xr: exit {p.returncode}\n--- stdout ---\n{p.stdout}--- stderr ---\n{p.stderr[-4000:]}")
        r = json.loads(p.stdout.strip().splitlines()[-1])
        print("xr:", json.dumps(r))
        if r["frames_rendered"] < 60 or r["frames_submitted"] < 60:
            sys.exit("fewer than 60 frames submitted")
        if not 0.055 < r["eye_separation_room_m"] < 0.071:
            sys.exit(f"the eyes are {r['eye_separation_room_m']} m apart, not the HMD's 63 mm")
        want = r["eye_separation_room_m"] * r["world_scale"]
        if abs(r["eye_separation_canvas_m"] - want) > 1e-9 + 1e-6 * want:
            sys.exit("the eyes in the canvas are not the room's eyes times the world scale")
        if r["strokes_begun"] < 1 or r["strokes_acked"] != r["strokes_begun"]:
            sys.exit("the scripted controller stroke was not painted and acked")
        after = strokes()
        if after < before + r["strokes_begun"]:
            sys.exit(f"the server counted {after - before} new strokes, not {r['strokes_begun']}")
        print(f"server strokes {before} -> {after}")

        # Without a runtime: a clear error, exit 1.
        bare = {k: v for k, v in env.items() if k != "XR_RUNTIME_JSON"}
        bare["XDG_CONFIG_HOME"] = tempfile.mkdtemp(dir=workdir)
        bare["XDG_CONFIG_DIRS"] = bare["XDG_CONFIG_HOME"]
        p = subprocess.run([client, "xr", "--connect", url, "--frames", "5"], env=bare,
                           capture_output=True, text=True, timeout=120)
        if p.returncode != 1 or "no OpenXR runtime is installed" not in p.stderr:
            sys.exit(f"without a runtime: exit {p.returncode}\n{p.stderr[-2000:]}")
    finally:
        stop_server(proc)
    if link_script:
        progressive_join_over_a_thin_link(server, client, link_script, workdir, env)
    print("ok")


if __name__ == "__main__":
    main()
