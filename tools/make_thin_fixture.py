#!/usr/bin/env python3
"""Writes tests/fixtures/thin/mitsuba_thindielectric.txt: Mitsuba 3's `thindielectric` BSDF
(a peer renderer's smooth thin sheet) sampled at several indices and angles, the reflected
and transmitted weights `f cos / pdf × pdf` it returns (R' and T'), for strata's thin-sheet
test (`render::material::thin_tests`). Run with /work/venv/bin/python (mitsuba 3)."""

import math
import pathlib

import mitsuba as mi

mi.set_variant("scalar_rgb")

OUT = pathlib.Path(__file__).resolve().parent.parent / "tests/fixtures/thin/mitsuba_thindielectric.txt"


def sample(bsdf, cos, sample1):
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(math.sqrt(1 - cos * cos), 0.0, cos)
    ctx = mi.BSDFContext()
    bs, weight = bsdf.sample(ctx, si, sample1, mi.Point2f(0.5, 0.5))
    # `weight` is f cos / pdf; the choice was made with probability bs.pdf (delta lobes).
    return bs.wo, weight[0] * bs.pdf


def main():
    lines = ["# eta cos R' T' (Mitsuba 3 thindielectric, int_ior=eta ext_ior=1)"]
    for eta in (1.2, 1.33, 1.5, 2.0, 3.0):
        bsdf = mi.load_dict({"type": "thindielectric", "int_ior": eta, "ext_ior": 1.0})
        for cos in (1.0, 0.9, 0.7, 0.5, 0.3, 0.1, 0.03):
            wo_r, r = sample(bsdf, cos, 0.0)
            wo_t, t = sample(bsdf, cos, 0.999999)
            assert wo_r[2] > 0 and wo_t[2] < 0, (wo_r, wo_t)
            lines.append(f"{eta} {cos} {r:.9f} {t:.9f}")
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
