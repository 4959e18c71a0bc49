#!/usr/bin/env python3
"""The headset client as a real OpenXR application, against a headless OpenXR runtime.

Usage: xr_headset.py PATH/TO/deepcanvas-server PATH/TO/deepcanvas-client RUNTIME.tar.gz WORKDIR

The runtime is Monado's null compositor and simulated HMD (../shared/tools/openxr; its README):
no display, no controllers, frames paced at 20 Hz. A server gets the generated scene; then
`deepcanvas-client xr --frames 60 --pose-trace T` must
- submit 60 rendered frames (stereo projection layers) and end the session cleanly;
- read both eyes' poses from the runtime and use them: their separation is the simulated HMD's
  63 mm, and 63 mm x the artist's world scale in the canvas;
- paint the trace's scripted controller stroke (the runtime has no controllers), which the
  server acks and counts;
and without a runtime the command fails saying there is none. Exit 77 (skipped) when the runtime
archive is not there.
"""
import json
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
import urllib.request

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from cli_support import start_server, stop_server  # noqa: E402


def main():
    server, client, runtime_tgz, workdir = sys.argv[1:5]
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
    print("ok")


if __name__ == "__main__":
    main()
