#!/usr/bin/env python3
"""The live view's samples per second against `strata render`'s at the same settings.

Runs, alternately and `--repeats` times each, `strata render` (its own "samples/s" line) and
`strata view` until converged (the view's `samples_per_second`: camera samples of its
progressive passes — bands and exact merges — per second of pass time), then prints both
medians and their ratio with the load average. Standard library only.

    python3 tools/view_vs_render.py --strata target/release/strata --res 320x240 --spp 16
"""

import argparse
import json
import os
import re
import statistics
import subprocess
import tempfile
import urllib.request


def render_rate(strata, scene, res, spp):
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run(
            [strata, "render", *scene, "--res", res, "--spp", str(spp), "-o", os.path.join(tmp, "r.exr")],
            capture_output=True, text=True, check=True,
        )
    match = re.search(r"([0-9.]+)([KM]?) samples/s", out.stdout + out.stderr)
    scale = {"": 1, "K": 1e3, "M": 1e6}[match.group(2)]
    return float(match.group(1)) * scale


def view_rate(strata, scene, res, spp):
    view = subprocess.Popen(
        [strata, "view", *scene, "--port", "0", "--res", res, "--spp", str(spp)],
        stdout=subprocess.PIPE, text=True,
    )
    try:
        url = view.stdout.readline().strip().split(" ", 2)[-1]
        after = 0
        while True:
            with urllib.request.urlopen(f"{url}status?after={after}", timeout=600) as r:
                status = json.load(r)
            if status["samples"] == spp and status["samples_per_second"]:
                return status["samples_per_second"]
            after = status["generation"]
    finally:
        view.kill()
        view.wait()


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--strata", default="target/release/strata")
    parser.add_argument("--scene", default=None)
    parser.add_argument("--res", default="320x240")
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    scene = [args.scene] if args.scene else []
    renders, views = [], []
    for _ in range(args.repeats):
        renders.append(render_rate(args.strata, scene, args.res, args.spp))
        views.append(view_rate(args.strata, scene, args.res, args.spp))
    render, view = statistics.median(renders), statistics.median(views)
    load = " ".join(open("/proc/loadavg").read().split()[:3])
    print(f"render {render / 1e3:.1f}K samples/s, view {view / 1e3:.1f}K samples/s, "
          f"view/render {view / render:.2f} ({args.res}, {args.spp} spp, load {load})")


if __name__ == "__main__":
    main()
