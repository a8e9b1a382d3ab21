#!/usr/bin/env python3
"""Writes tests/fixtures/aniso/mitsuba_ggx.txt: anisotropic GGX values that Mitsuba 3 computes,
for `cargo test --release --lib material::aniso_tests`. Each line is one case,
space-separated:

  D           ax ay  mx my mz                  D(m)
  G1          ax ay  vx vy vz                  G1(v)                  (Smith masking)
  VNDF        ax ay  wox woy woz  mx my mz     D_wo(m)                (visible-normal density)
  CONDUCTOR   ax ay  eta k  wox woy woz  wix wiy wiz   f(wo, wi)
  DIELECTRIC  ax ay  eta    wox woy woz  wix wiy wiz   f(wo, wi)

Directions are in the lobe's local frame (x the tangent, along which the width is ax; z the
normal); wo looks towards the viewer, wi towards the light, and f excludes the cosine. The
references are Mitsuba's `MicrofacetDistribution` (GGX, `alpha_u` = ax, `alpha_v` = ay) and
its `roughconductor` and `roughdielectric` plugins (`scalar_rgb`, radiance transport, the
dielectric of interior index eta in air), none of them strata's code. Mitsuba's BSDFs use the
separable Smith term G1(wo) G1(wi); strata the height-correlated one 1 / (1 + Λ(wo) + Λ(wi))
(Heitz 2014). The expected f is Mitsuba's value divided by |cos θi|, times the ratio of the
two terms, both computed from Mitsuba's own G1 (Λ = 1 / G1 − 1): still only Mitsuba's numbers.

Usage: /work/venv/bin/python tools/make_aniso_fixtures.py  (mitsuba, numpy)
"""

import math
import os

import mitsuba as mi
import numpy as np

mi.set_variant("scalar_rgb")

OUT = os.path.join(os.path.dirname(__file__), "..", "tests", "fixtures", "aniso", "mitsuba_ggx.txt")
WIDTHS = [(0.1, 0.4), (0.4, 0.1), (0.05, 0.3), (0.3, 0.3), (0.6, 0.15), (0.2, 0.02)]
rng = np.random.default_rng(22)


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def hemisphere(min_cos=0.05):
    while True:
        v = unit(rng.normal(size=3))
        if abs(v[2]) >= min_cos:
            return np.array([v[0], v[1], abs(v[2])])


def fmt(xs):
    return " ".join(f"{float(x):.9g}" for x in xs)


def g1_up(dist, v):
    """Mitsuba's Smith G1 of direction v, seen from its own side."""
    up = mi.Vector3f(float(v[0]), float(v[1]), abs(float(v[2])))
    return float(dist.smith_g1(up, mi.Vector3f(0, 0, 1)))


def reflect(wo, m):
    return 2.0 * np.dot(wo, m) * m - wo


def refract(wo, m, eta):
    """wo refracted through microfacet m (facing wo's side) into the medium of relative index eta."""
    c = np.dot(wo, m)
    sin2 = (1.0 - c * c) / (eta * eta)
    if sin2 >= 1.0:
        return None
    return unit(-wo / eta + (c / eta - math.sqrt(1.0 - sin2)) * m)


def sampled_normal(dist, wo):
    """A microfacet normal Mitsuba's visible-normal sampler draws for wo (seen from its side), so
    that half the BSDF cases lie where the lobe has its energy."""
    up = np.array([wo[0], wo[1], abs(wo[2])])
    m, _ = dist.sample(mi.Vector3f(*up), mi.Point2f(*rng.random(2)))
    return np.array([m[0], m[1], m[2]])


def correlated(dist, wo, wi):
    """Height-correlated G2 over separable G1 G1, from Mitsuba's G1 alone."""
    go, gi = g1_up(dist, wo), g1_up(dist, wi)
    lo, li = 1.0 / go - 1.0, 1.0 / gi - 1.0
    return (1.0 / (1.0 + lo + li)) / (go * gi)


def interaction(wo):
    si = mi.SurfaceInteraction3f()
    si.p = mi.Point3f(0, 0, 0)
    si.n = mi.Normal3f(0, 0, 1)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.wi = mi.Vector3f(*[float(x) for x in wo])
    return si


def main():
    lines = []
    ctx = mi.BSDFContext()
    for ax, ay in WIDTHS:
        dist = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, ax, ay)
        for _ in range(6):
            m = hemisphere(0.2)
            lines.append(f"D {ax} {ay} {fmt(m)} {float(dist.eval(mi.Vector3f(*m))):.9g}")
        for _ in range(4):
            v = hemisphere()
            lines.append(f"G1 {ax} {ay} {fmt(v)} {g1_up(dist, v):.9g}")
        for _ in range(6):
            wo = hemisphere(0.1)
            m = hemisphere(0.2)
            if np.dot(wo, m) <= 0:
                m = np.array([-m[0], -m[1], m[2]])
            pdf = float(dist.pdf(mi.Vector3f(*wo), mi.Vector3f(*m)))
            lines.append(f"VNDF {ax} {ay} {fmt(wo)} {fmt(m)} {pdf:.9g}")
        eta, k = 1.3, 2.7
        conductor = mi.load_dict(
            {"type": "roughconductor", "distribution": "ggx", "alpha_u": ax, "alpha_v": ay, "eta": eta, "k": k}
        )
        for case in range(8):
            wo, wi = hemisphere(0.1), hemisphere(0.1)
            if case % 2:
                wi = reflect(wo, sampled_normal(dist, wo))
                if wi[2] < 0.05:
                    continue
            v = conductor.eval(ctx, interaction(wo), mi.Vector3f(*wi))
            f = float(v[0]) / wi[2] * correlated(dist, wo, wi)
            lines.append(f"CONDUCTOR {ax} {ay} {eta} {k} {fmt(wo)} {fmt(wi)} {f:.9g}")
        eta = 1.5
        dielectric = mi.load_dict(
            {"type": "roughdielectric", "distribution": "ggx", "alpha_u": ax, "alpha_v": ay, "int_ior": eta, "ext_ior": 1.0}
        )
        for case in range(24):
            wo, wi = hemisphere(0.1), hemisphere(0.1)
            # Reflection outside, transmission both ways, reflection inside.
            if case % 4 == 1:
                wi[2] = -wi[2]
            elif case % 4 == 2:
                wo[2] = -wo[2]
            elif case % 4 == 3:
                wo[2], wi[2] = -wo[2], -wi[2]
            if case >= 12:
                # Where the lobe has its energy: about a normal Mitsuba samples for wo.
                m = sampled_normal(dist, wo)
                side = 1.0 if wo[2] > 0 else -1.0
                m = m * side
                if case % 4 in (0, 3):
                    wi = reflect(wo, m)
                else:
                    wi = refract(wo, m, eta if side > 0 else 1.0 / eta)
                if wi is None or abs(wi[2]) < 0.05 or (wi[2] > 0) != (case % 4 in (0, 2)):
                    continue
            v = dielectric.eval(ctx, interaction(wo), mi.Vector3f(*wi))
            f = float(v[0]) / abs(wi[2]) * correlated(dist, wo, wi)
            if not math.isfinite(f):
                continue
            lines.append(f"DIELECTRIC {ax} {ay} {eta} {fmt(wo)} {fmt(wi)} {f:.9g}")
    os.makedirs(os.path.dirname(OUT), exist_ok=True)
    with open(OUT, "w") as out:
        out.write("# Written by tools/make_aniso_fixtures.py from Mitsuba 3 (see its docstring); do not edit.\n")
        out.write("\n".join(lines) + "\n")
    print(f"{len(lines)} cases -> {OUT}")


if __name__ == "__main__":
    main()
