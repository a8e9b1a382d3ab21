"""Variance per sample against samples per pixel, by the two-seed method, for strata's
samplers and, on the comparison scenes, Mitsuba 3's and Cycles' (issue 27: variance per spp
must fall as spp grows with a low-discrepancy sampler).

For each renderer, sampler and spp, renders the scene twice with different seeds; the variance
of one render's pixel mean is mean((a - b)^2) / 2 over pixels and channels, and variance per
spp is that times spp (flat for independent numbers, falling for stratified ones). Optional
tool: `pip install OpenEXR numpy` (strata alone); mitsuba==3.9.1 for --mitsuba, bpy for
--cycles, matplotlib for --svg.

    python3 tools/variance_per_spp.py [--strata target/release/strata] [--scene S.usda | matte]
        [--res 160x120] [--spp 1,4,16,64,256] [--samplers sobol,independent]
        [--mitsuba independent,multijitter,ldsampler] [--cycles] [--max-depth 8]
        [--csv FILE] [--svg FILE] [--crop X0,Y0,X1,Y1] [--pairs N]
        [--strata-args="--max-depth 16"]

--scene takes a USD file (strata only), or the name of a comparison scene of
tools/compare_mitsuba.py (matte, mcg, layers, layers_dome), which Mitsuba renders too; Cycles
renders `matte` only (tools/compare_cycles.py). Default: strata's embedded scene. A sampler
that cannot take a sample count (Mitsuba's ldsampler takes powers of 4) has no point there.

--crop measures one region only (pixels X0 <= x < X1, Y0 <= y < Y1), e.g. the rough glass
sphere of scenes/compare/metal_coat_glass.usda at 160x120: --crop 113,52,133,72. --pairs
averages the figure over N seed pairs (1,2), (3,4), ...
"""
import argparse
import csv
import os
import subprocess
import sys
import tempfile

import numpy as np

from rmse import load  # tools/rmse.py: the beauty RGB of an EXR


def render(args, sampler, spp, seed, out):
    cmd = [args.strata, "render"]
    if args.scene_file:
        cmd.append(args.scene_file)
    cmd += ["-o", out, "--spp", str(spp), "--seed", str(seed), "--res", args.res, "--sampler", sampler]
    if args.max_depth:
        cmd += ["--max-depth", str(args.max_depth)]
    cmd += args.strata_args.split()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    img = load(out)
    if args.crop:
        x0, y0, x1, y1 = (int(v) for v in args.crop.split(","))
        img = img[y0:y1, x0:x1]
    return img


def two_seed(a, b, spp):
    """Variance per spp of a pixel from two renders with different seeds."""
    return float(np.mean((a - b) ** 2) / 2 * spp)


def mitsuba_rows(args, ladder, res, rows):
    import compare_mitsuba as cm
    mi = cm.load_mitsuba(args.variant)
    mi.set_log_level(mi.LogLevel.Error)  # its samplers' rounding warnings: such points are left out
    for sampler in args.mitsuba.split(","):
        for spp in ladder:
            scene = cm.mitsuba_scene(mi, cm.SCENES[args.scene], res, spp, args.max_depth, [], sampler)
            if scene.sensors()[0].sampler().sample_count() != spp:  # e.g. ldsampler wants 4^k
                rows[(f"Mitsuba {sampler}", spp)] = float("nan")
                continue
            a, b = (np.array(mi.render(scene, seed=s), dtype=np.float64) for s in (1, 2))
            rows[(f"Mitsuba {sampler}", spp)] = two_seed(a, b, spp)
    return f"Mitsuba {mi.__version__} {mi.variant()}"


def cycles_rows(args, ladder, res, rows, tmp):
    import compare_cycles as cc
    got, version, pattern = cc.cycles_renders(res, [(spp, s) for spp in ladder for s in (1, 2)],
                                              args.max_depth, 2, tmp, timed=False)
    for spp in ladder:
        rows[(f"Cycles {pattern.lower().replace('_', ' ')}", spp)] = two_seed(got[(spp, 1)][0], got[(spp, 2)][0], spp)
    return f"Cycles {version}"


def chart(path, names, ladder, rows, title):
    """Log-log lines of variance per spp against spp, one per renderer and sampler, as SVG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    plt.rcParams["svg.fonttype"] = "none"  # text stays text: a small, diffable file
    plt.rcParams["svg.hashsalt"] = "strata"
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name in names:
        style = "-" if name.startswith("strata") else "--" if name.startswith("Mitsuba") else ":"
        ax.plot(ladder, [rows[(name, spp)] for spp in ladder], style, marker="o", label=name)
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xticks(ladder, [str(s) for s in ladder])
    ax.set_xlabel("samples per pixel")
    ax.set_ylabel("variance per spp (two-seed method)")
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, metadata={"Date": None})


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--strata", default="target/release/strata")
    parser.add_argument("--scene", default=None, help="a USD scene or a comparison scene name (default: the embedded scene)")
    parser.add_argument("--res", default="160x120")
    parser.add_argument("--spp", default="1,4,16,64,256")
    parser.add_argument("--samplers", default="sobol,independent", help="strata's samplers")
    parser.add_argument("--max-depth", type=int, default=None, help="strata --max-depth (Mitsuba: + 1; Cycles: - 1)")
    parser.add_argument("--mitsuba", default="", help="Mitsuba samplers, e.g. independent,multijitter,ldsampler")
    parser.add_argument("--variant", default="llvm_ad_rgb")
    parser.add_argument("--cycles", action="store_true", help="Cycles too (scene matte only)")
    parser.add_argument("--csv", default=None)
    parser.add_argument("--svg", default=None)
    parser.add_argument("--crop", default=None, help="X0,Y0,X1,Y1: measure this pixel region only (strata)")
    parser.add_argument("--pairs", type=int, default=1, help="seed pairs to average over (strata)")
    parser.add_argument("--strata-args", default="", help="extra arguments of `strata render`")
    args = parser.parse_args()
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    ladder = [int(s) for s in args.spp.split(",")]
    res = tuple(int(v) for v in args.res.split("x"))
    named = args.scene is not None and not os.path.splitext(args.scene)[1]
    args.scene_file = args.scene
    if named:
        import compare_mitsuba as cm
        args.scene_file = os.path.join(cm.ROOT, cm.SCENES[args.scene]["usda"])
        args.max_depth = args.max_depth or 8
    elif args.mitsuba or args.cycles:
        sys.exit("--mitsuba and --cycles need a comparison scene name as --scene")
    if args.cycles and args.scene != "matte":
        sys.exit("--cycles: Cycles has the matte scene only")
    rows, versions = {}, ["strata"]
    with tempfile.TemporaryDirectory() as tmp:
        for sampler in args.samplers.split(","):
            for spp in ladder:
                total = 0.0
                for k in range(args.pairs):
                    a = render(args, sampler, spp, 2 * k + 1, os.path.join(tmp, "a.exr"))
                    b = render(args, sampler, spp, 2 * k + 2, os.path.join(tmp, "b.exr"))
                    total += two_seed(a, b, spp)
                rows[(f"strata {sampler}", spp)] = total / args.pairs
        if args.mitsuba:
            versions.append(mitsuba_rows(args, ladder, res, rows))
        if args.cycles:
            versions.append(cycles_rows(args, ladder, res, rows, tmp))
    names = list(dict.fromkeys(name for name, _ in rows))
    title = (f"variance per spp (two-seed method, {args.pairs} pair(s)), scene {args.scene or '(embedded default)'}, {args.res}"
             + (f", --max-depth {args.max_depth}" if args.max_depth else "")
             + (f", pixels {args.crop}" if args.crop else ""))
    print(f"{title}; {', '.join(versions)}")
    print("| spp | " + " | ".join(names) + " |")
    print("|---" * (len(names) + 1) + "|")
    for spp in ladder:
        print(f"| {spp} | " + " | ".join(f"{rows[(n, spp)]:.4g}" for n in names) + " |")
    if len(names) > 1:
        first = names[0]
        print(f"\nratio to {first} at each spp: " + "; ".join(
            f"{n}: " + " · ".join(f"{rows[(n, spp)] / rows[(first, spp)]:.2f}" for spp in ladder) for n in names[1:]))
    if args.csv:
        with open(args.csv, "w", newline="") as fh:
            wr = csv.writer(fh)
            wr.writerow(["renderer_sampler", "spp", "variance_per_spp", "scene", "res", "versions"])
            for (n, spp), v in rows.items():
                wr.writerow([n, spp, f"{v:.6g}", args.scene or "embedded", args.res, "; ".join(versions)])
        print(f"wrote {args.csv}")
    if args.svg:
        chart(args.svg, names, ladder, rows, title)
        print(f"wrote {args.svg}")


if __name__ == "__main__":
    sys.exit(main())
