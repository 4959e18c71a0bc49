#!/usr/bin/env python3
"""An exported OpenVDB file opens in Blender's volume import (where Blender is installed).

Usage: export_blender.py PATH/TO/deepcanvas-server WORKDIR

`deepcanvas-server export demo.apa --out demo.vdb --voxel-size 0.005`, then Blender in the
background imports it (bpy.ops.object.volume_import) and must list the grids `density` (float)
and `Cd` (vector), with the volume's bounds where the painting is (canvas metres, within 2 cm;
the painting's extent is written in the test).
Exit 77 (skipped) when Blender (Debian `blender`, not installed by setup.sh: it is large) or the
paintings are missing.
"""
import os
import shutil
import subprocess
import sys


def main():
    server, workdir = sys.argv[1:3]
    blender = shutil.which("blender")
    paintings = os.environ.get("DEEPCANVAS_PAINTINGS", "")
    demo = os.path.join(paintings, "demo.apa")
    if not blender or not os.path.exists(demo):
        print("blender or $DEEPCANVAS_PAINTINGS/demo.apa missing: skipped")
        sys.exit(77)
    workdir = os.path.join(workdir, "export_blender")
    shutil.rmtree(workdir, ignore_errors=True)
    os.makedirs(workdir)
    vdb = os.path.join(workdir, "demo.vdb")
    subprocess.run([server, "export", demo, "--out", vdb, "--voxel-size", "0.005", "--quiet"],
                   check=True, capture_output=True, timeout=300)
    script = os.path.join(workdir, "import.py")
    with open(script, "w") as f:
        f.write(f"""
import bpy
bpy.ops.object.volume_import(filepath={vdb!r})
ob = bpy.context.selected_objects[0]
ob.data.grids.load()
print("GRIDS", sorted((g.name, g.data_type) for g in ob.data.grids))
lo, hi = ob.bound_box[0], ob.bound_box[6]
print("BOUNDS", *[round(v, 4) for v in (*lo, *hi)])
""")
    p = subprocess.run([blender, "-b", "--factory-startup", "--python", script], capture_output=True,
                       text=True, timeout=600)
    grids = [l for l in p.stdout.splitlines() if l.startswith("GRIDS")]
    bounds = [l for l in p.stdout.splitlines() if l.startswith("BOUNDS")]
    if not grids or not bounds:
        sys.exit("Blender did not import the file:\n" + p.stdout[-3000:] + p.stderr[-3000:])
    print(grids[0])
    print(bounds[0])
    if grids[0] != "GRIDS [('Cd', 'VECTOR_FLOAT'), ('density', 'FLOAT')]":
        sys.exit("Blender sees other grids than density (float) and Cd (vector)")
    lo_hi = [float(v) for v in bounds[0].split()[1:]]
    # demo.apa's painted extent in canvas metres (its strokes' sample spheres), as exported.
    want = [-0.76, 0.92, 0.61, 0.08, 1.68, 0.95]
    if any(abs(a - b) > 0.02 for a, b in zip(lo_hi, want)):
        sys.exit(f"the volume in Blender lies at {lo_hi}, not where the painting is ({want})")
    print("ok")


if __name__ == "__main__":
    main()
