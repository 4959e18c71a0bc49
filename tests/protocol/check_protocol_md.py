"""Runs PROTOCOL.md's Python block decoder on frames the C++ encoder wrote.

usage: check_protocol_md.py PROTOCOL.md DIR
Decodes every DIR/*.frame with decode_block() taken verbatim from the document's python code
block and writes DIR/<name>.json: {"epoch", "block", "version", "first", "cells", pools...}.
"""
import json
import pathlib
import re
import sys

doc = pathlib.Path(sys.argv[1]).read_text()
code = re.search(r"```python\n(.*?)```", doc, re.S).group(1)
namespace = {"__name__": "protocol_md"}
exec(compile(code, "PROTOCOL.md", "exec"), namespace)
decode_block = namespace["decode_block"]

for frame in sorted(pathlib.Path(sys.argv[2]).glob("*.frame")):
    epoch, block, bver, first, cells, pools = decode_block(frame.read_bytes())
    out = {"epoch": epoch, "block": block, "version": bver, "first": first, "cells": cells}
    for k, v in pools.items():
        out[k] = list(v)
    frame.with_suffix(".json").write_text(json.dumps(out))
