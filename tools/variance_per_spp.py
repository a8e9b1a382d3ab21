"""Variance per sample against samples per pixel, by the two-seed method, for strata's
samplers (issue 27: variance per spp must fall as spp grows with a low-discrepancy sampler).

For each sampler and spp, renders the scene twice with different seeds; the variance of one
render's pixel mean is mean((a - b)^2) / 2 over pixels and channels, and variance per spp is
that times spp (flat for independent numbers, falling for stratified ones). Optional tool:
`pip install OpenEXR numpy`.

    python3 tools/variance_per_spp.py [--strata target/release/strata] [--scene S.usda]
        [--res 160x120] [--spp 1,4,16,64,256] [--samplers sobol,independent]
        [--crop X0,Y0,X1,Y1] [--pairs N] [--strata-args="--max-depth 16"]

--crop measures one region only (pixels X0 <= x < X1, Y0 <= y < Y1), e.g. the rough glass
sphere of scenes/compare/metal_coat_glass.usda at 160x120: --crop 113,52,133,72. --pairs
averages the figure over N seed pairs (1,2), (3,4), ...
"""
import argparse
import os
import subprocess
import sys
import tempfile

import numpy as np

from rmse import load  # tools/rmse.py: the beauty RGB of an EXR


def render(args, sampler, spp, seed, out):
    cmd = [args.strata, "render"]
    if args.scene:
        cmd.append(args.scene)
    cmd += ["-o", out, "--spp", str(spp), "--seed", str(seed), "--res", args.res, "--sampler", sampler]
    cmd += args.strata_args.split()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    img = load(out)
    if args.crop:
        x0, y0, x1, y1 = (int(v) for v in args.crop.split(","))
        img = img[y0:y1, x0:x1]
    return img


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--strata", default="target/release/strata")
    parser.add_argument("--scene", default=None, help="a USD scene (default: the embedded scene)")
    parser.add_argument("--res", default="160x120")
    parser.add_argument("--spp", default="1,4,16,64,256")
    parser.add_argument("--samplers", default="sobol,independent")
    parser.add_argument("--crop", default=None, help="X0,Y0,X1,Y1: measure this pixel region only")
    parser.add_argument("--pairs", type=int, default=1, help="seed pairs to average over")
    parser.add_argument("--strata-args", default="", help="extra arguments of `strata render`")
    args = parser.parse_args()
    ladder = [int(s) for s in args.spp.split(",")]
    samplers = args.samplers.split(",")
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for sampler in samplers:
            for spp in ladder:
                total = 0.0
                for k in range(args.pairs):
                    a = render(args, sampler, spp, 2 * k + 1, os.path.join(tmp, "a.exr"))
                    b = render(args, sampler, spp, 2 * k + 2, os.path.join(tmp, "b.exr"))
                    total += float(np.mean((a - b) ** 2) / 2 * spp)
                rows[(sampler, spp)] = total / args.pairs
    region = f", pixels {args.crop}" if args.crop else ""
    print(f"variance per spp (two-seed method, {args.pairs} pair(s)), scene {args.scene or '(embedded default)'}, "
          f"{args.res}{region}")
    print("| spp | " + " | ".join(samplers) + (" | ratio |" if len(samplers) == 2 else " |"))
    print("|---" * (len(samplers) + 1 + (len(samplers) == 2)) + "|")
    for spp in ladder:
        cells = [f"{rows[(s, spp)]:.4g}" for s in samplers]
        ratio = [f"{rows[(samplers[1], spp)] / rows[(samplers[0], spp)]:.2f}x"] if len(samplers) == 2 else []
        print(f"| {spp} | " + " | ".join(cells + ratio) + " |")


if __name__ == "__main__":
    sys.exit(main())
