"""strata against Mitsuba 3: images compared region by region, and the timing of docs/MITSUBA.md's and docs/PERFORMANCE.md's
Performance section. Not part of the test suite (`cargo test` needs neither Python nor Mitsuba).

    pip install mitsuba numpy flip-evaluator
    apt-get install libllvm19        # for the llvm_ad_rgb variant; scalar_rgb needs nothing
    export DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so
    cargo build --release
    python3 tools/compare_mitsuba.py images [--scenes matte,mcg,layers_dome,layers,thin]
        [--spp 1024] [--res 320x240] [--max-depth 16] [--seed 1] [--out DIR] [--csv FILE]
        [--variant llvm_ad_rgb|scalar_rgb] [--strata-args=--weighted]
    python3 tools/compare_mitsuba.py coat     # the glossy / roughplastic model difference alone
    python3 tools/compare_mitsuba.py timing   # matte ball, 640x480, 64 spp, three Mitsuba runs
                                              # (strata: render ... --spp 64 --max-depth 8)
    python3 tools/compare_mitsuba.py measure [--scenes matte,mcg,layers,layers_dome] [--spp 64]
        [--res 320x240] [--threads 2] [--max-depth 8] [--csv FILE]
                       # equal-error CPU time, strata / Mitsuba (docs/PERFORMANCE.md's table)
    python3 tools/compare_mitsuba.py check    # CI (below)

`measure` renders each scene with strata and Mitsuba at the same resolution, thread count and
spp, two seeds each, and a 1-spp render of each. Time per spp is CPU seconds (user + sys: of
the strata child, from os.wait4; of this process for Mitsuba, every thread, with its kernels
compiled and cached first), the 1-spp render's taken off: what each more sample costs.
Variance per spp is the two-seed method's mean((a - b)^2) / 2 x spp over pixels and channels;
the equal-error time ratio is the product of the two ratios. It prints the agreement of the
mean images (whole image and per region, as `check` judges it), the CPU model and the load
average with the markdown table, and writes every figure to --csv. tools/compare_cycles.py does
the same against Cycles; tools/measure_performance.sh runs both and the variance chart.

`images` renders each scene with `target/release/strata render` and with Mitsuba's `path`
integrator (box filter, independent sampler, same resolution and spp, Mitsuba max_depth =
strata's --max-depth + 1: Mitsuba counts the emitter segment), then reports per object region
(pixels whose 4x4 sub-pixel rays all hit the same object, eroded by one pixel; regions are ray
cast here from the scene description):
  - the relative difference of the region's mean luminance, strata over Mitsuba, with two
    standard errors of the per-pixel differences (the part of the figure noise can explain);
    the worst RGB channel's difference;
  - the relative mean absolute difference, mean |L_s - L_m| / mean L_m;
  - the mean HDR-FLIP error (flip-evaluator), Mitsuba as reference;
each of the last two next to its noise level: the root mean square of the same figure between
two strata renders and between two Mitsuba renders with other seeds, which is what the
strata-Mitsuba figure would be if the images differed by (Gaussian) noise alone.
Renders, side-by-side PNGs and FLIP maps go to --out; the table to stdout and --csv.

Each scene is described once below (`SCENES`) with the numbers of its .usda, and mapped to
Mitsuba as exactly as the two models allow:
  camera     UsdGeom: looks down local -Z, fov_x = 2 atan(horizontalAperture / 2 focalLength);
             Mitsuba's perspective looks down +Z with +X to the left: to_world = M diag(-1,1,-1).
  DomeLight  constant emitter; radiance = intensity (strata: intensity 2^exposure color, and for
             area lights / area if normalize; these scenes author intensity alone).
  RectLight  UsdLux: width along local X, height along Y, emits along local -Z, radiance =
             intensity. Mitsuba's rectangle is [-1,1]^2 emitting along +Z:
             to_world = M scale(w/2, h/2, 1) rotX(180). strata's lights are not geometry, so the
             rectangle gets a `null` BSDF (rays pass through its back, as in strata).
  diffuse    diffuse (inside twosided: strata's reflection BSDFs are two-sided).
  metal      roughconductor ggx, alpha = roughness^2 (strata: alpha = r^2), (eta, k) per channel
             from strata's Gulbrandsen conversion of reflectivity / edge tint. Same Fresnel and
             D; Mitsuba's Smith G is separable, strata's height-correlated.
  glass      roughdielectric ggx, alpha = roughness^2, int_ior = ior, ext_ior = 1, transmittance
             = tint. Same model but for the separable vs height-correlated G.
  glossy     roughplastic ggx, alpha = roughness^2, int_ior = ior, ext_ior = 1, linear.
             NOT the same model: strata's base is albedo/pi (1 - F(mu_i))(1 - F(mu_o)) with a
             smooth-interface Fresnel and no internal re-scattering; roughplastic's is
             rho / (1 - R_int) / eta^2 t(mu_i) t(mu_o) / pi with rough-interface transmittances t.
             diffuse_reflectance = albedo eta^2 (1 - R_int) makes the two agree up to t vs 1 - F.
  layers     two layers, top mask m over an opaque bottom: blendbsdf weight m, bsdf_0 = bottom,
             bsdf_1 = top ((1 - m) bottom + m top, strata's rule-5 weights).
  opacity    a single layer with mask 0.5: mask bsdf, opacity 0.5.
  thin       a smooth thin-walled dielectric sheet (with_thin_walled): thindielectric, int_ior =
             ior, ext_ior = 1. The same model: reflectance 2R / (1 + R), transmission straight
             through; both block shadow rays.
"""
import argparse, csv, datetime, math, os, resource, subprocess, sys, tempfile, time
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# ------------------------------------------------------------------------------------ scenes
# Everything as authored in scenes/compare/*.usda (a .usda edit must be mirrored here).

CAMERA = dict(translate=(0, 1.4, 6.5), rotate_xyz=(-5.27, 0, 0), focal=35.0, aperture=36.0)
FLOOR = ((-6, 0, -6), (-6, 0, 6), (6, 0, 6), (6, 0, -6))
KEY = dict(translate=(2, 4, 3), rotate_xyz=(-44.15, 33.69, 0), width=3.0, height=1.5, intensity=10.0)
CARD = ((-2, 0, 1.5), (0.2, 0, 1.5), (0.2, 1.6, 1.5), (-2, 1.6, 1.5))


def diffuse(albedo):
    return ('diffuse', dict(albedo=albedo))


SCENES = {
    'matte': dict(
        usda='scenes/compare/matte_ball.usda', dome=1.0, rect=None,
        objects=[('floor', ('quad', FLOOR), diffuse(0.5)),
                 ('ball', ('sphere', (0, 0.8, 0), 0.8), diffuse(0.8))]),
    'mcg': dict(
        usda='scenes/compare/metal_coat_glass.usda', dome=0.5, rect=KEY,
        objects=[('floor', ('quad', FLOOR), diffuse(0.5)),
                 ('metal', ('sphere', (-1.8, 0.7, 0), 0.7),
                  ('metal', dict(reflectivity=(0.95, 0.64, 0.54), edge_tint=(1.0, 0.85, 0.7), roughness=0.35))),
                 ('coated', ('sphere', (0, 0.7, 0), 0.7),
                  ('glossy', dict(albedo=(0.15, 0.3, 0.6), roughness=0.3, ior=1.5))),
                 ('glass', ('sphere', (1.8, 0.7, 0), 0.7), ('glass', dict(tint=1.0, roughness=0.2, ior=1.5)))]),
}
_LAYERED_BALL = ('ball', ('sphere', (0.6, 0.8, 0), 0.8),
                 ('layers', dict(bottom=diffuse((0.8, 0.35, 0.1)), top=diffuse((0.1, 0.3, 0.8)), mask=0.3)))
_CARD = ('card', ('quad', CARD), ('opacity', dict(bsdf=diffuse((0.9, 0.85, 0.2)), opacity=0.5)))
SCENES['layers_dome'] = dict(usda='scenes/compare/layers_card_dome.usda', dome=1.0, rect=None,
                             objects=[('floor', ('quad', FLOOR), diffuse(0.5)), _LAYERED_BALL, _CARD])
SCENES['layers'] = dict(usda='scenes/compare/layers_card.usda', dome=0.5, rect=KEY,
                        objects=[('floor', ('quad', FLOOR), diffuse(0.5)), _LAYERED_BALL, _CARD])
PANE = ((-2, 0, 1.5), (1, 0, 1.5), (1, 1.6, 1.5), (-2, 1.6, 1.5))
SCENES['thin'] = dict(usda='scenes/compare/thin_pane.usda', dome=0.5, rect=KEY,
                      objects=[('floor', ('quad', FLOOR), diffuse(0.5)),
                               ('ball', ('sphere', (0.6, 0.8, 0), 0.8), diffuse((0.8, 0.35, 0.1))),
                               ('pane', ('quad', PANE), ('thin', dict(ior=1.5)))])

# ------------------------------------------------------------------------------- transforms


def translate(t):
    m = np.eye(4)
    m[:3, 3] = t
    return m


def rotate(axis, deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    i, j = {'x': (1, 2), 'y': (2, 0), 'z': (0, 1)}[axis]
    m = np.eye(4)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def scale(s):
    return np.diag([s[0], s[1], s[2], 1.0])


def usd_xform(translate_v, rotate_xyz):
    """xformOpOrder [translate, rotateXYZ]: M = T Rz Ry Rx (column vectors)."""
    x, y, z = rotate_xyz
    return translate(translate_v) @ rotate('z', z) @ rotate('y', y) @ rotate('x', x)


def luminance(img):
    return img[..., 0] * 0.2126 + img[..., 1] * 0.7152 + img[..., 2] * 0.0722

# --------------------------------------------------------------------------- BSDF mapping


def gulbrandsen(r, g):
    """strata's render::microfacet::gulbrandsen (f64), with metal()'s clamps."""
    r = min(max(r, 0.0), 0.999)
    g = min(max(g, 0.0), 1.0)
    n_min = (1 - r) / (1 + r)
    sr = math.sqrt(r)
    n_max = (1 + sr) / (1 - sr)
    n = n_min * g + (1 - g) * n_max
    k2 = ((n + 1) ** 2 * r - (n - 1) ** 2) / (1 - r)
    return n, math.sqrt(max(k2, 0.0))


def rough_internal_reflectance(mi, alpha, eta):
    """roughplastic's m_internal_reflectance: 2 * mean over 64 mu of mu * R_rough(mu, 1/eta)."""
    mu = np.maximum(1e-6, np.linspace(0, 1, 64)).astype(np.float32)
    try:  # bound for the JIT variants only
        wi = mi.Vector3f(np.sqrt(1 - mu * mu), np.zeros_like(mu), mu)
        r = np.array(mi.eval_reflectance(mi.MicrofacetType.GGX, alpha, alpha, wi, 1 / eta))
    except TypeError:
        r = np.array([_rough_reflectance_np(alpha, m, 1 / eta) for m in mu])
    return float(np.mean(r * mu) * 2)


def _rough_reflectance_np(alpha, mu, eta, n=96):
    """Directional albedo of a GGX dielectric reflection, E[F(wi.m) G1(wo)] over visible normals
    (Heitz 2018 sampling on a Gauss-Legendre grid): the scalar variant's fallback."""
    x, w = np.polynomial.legendre.leggauss(n)
    u1, u2 = np.meshgrid((x + 1) / 2, (x + 1) / 2)
    ww = np.outer(w, w) / 4
    wi = np.array([math.sqrt(max(0.0, 1 - mu * mu)), 0.0, mu])
    vh = np.array([alpha * wi[0], alpha * wi[1], wi[2]])
    vh /= np.linalg.norm(vh)
    t1 = np.array([1.0, 0, 0]) if vh[2] > 0.9999 else np.cross([0, 0, 1.0], vh) / np.linalg.norm(np.cross([0, 0, 1.0], vh))
    t2 = np.cross(vh, t1)
    r = np.sqrt(u1)
    phi = 2 * np.pi * u2
    p1, p2 = r * np.cos(phi), r * np.sin(phi)
    s = 0.5 * (1 + vh[2])
    p2 = (1 - s) * np.sqrt(np.maximum(0, 1 - p1 * p1)) + s * p2
    nh = p1[..., None] * t1 + p2[..., None] * t2 + np.sqrt(np.maximum(0, 1 - p1 * p1 - p2 * p2))[..., None] * vh
    m = np.stack([alpha * nh[..., 0], alpha * nh[..., 1], np.maximum(1e-6, nh[..., 2])], -1)
    m /= np.linalg.norm(m, axis=-1, keepdims=True)
    c = m @ wi
    wo = 2 * c[..., None] * m - wi
    sin2_t = (1 - c * c) / (eta * eta)
    cos_t = np.sqrt(np.maximum(0, 1 - sin2_t))
    rs = (c - eta * cos_t) / (c + eta * cos_t)
    rp = (eta * c - cos_t) / (eta * c + cos_t)
    f = np.where(sin2_t >= 1, 1.0, 0.5 * (rs * rs + rp * rp))
    tan2 = (wo[..., 0] ** 2 + wo[..., 1] ** 2) / np.maximum(wo[..., 2] ** 2, 1e-12)
    g1 = np.where(wo[..., 2] > 0, 2 / (1 + np.sqrt(1 + alpha * alpha * tan2)), 0.0)
    return float(np.sum(ww * f * g1))


def rgb(v):
    v = (v, v, v) if np.isscalar(v) else tuple(v)
    return {'type': 'rgb', 'value': [float(c) for c in v]}


def mitsuba_bsdf(mi, bsdf, notes):
    kind, p = bsdf
    if kind == 'diffuse':
        return {'type': 'twosided', 'bsdf': {'type': 'diffuse', 'reflectance': rgb(p['albedo'])}}
    if kind == 'metal':
        ek = [gulbrandsen(r, g) for r, g in zip(p['reflectivity'], p['edge_tint'])]
        notes.append(f"metal: eta = {[round(e, 4) for e, _ in ek]}, k = {[round(k, 4) for _, k in ek]}, "
                     f"alpha = {p['roughness'] ** 2:.4f}")
        return {'type': 'twosided', 'bsdf': {
            'type': 'roughconductor', 'distribution': 'ggx', 'alpha': p['roughness'] ** 2,
            'eta': rgb([e for e, _ in ek]), 'k': rgb([k for _, k in ek])}}
    if kind == 'glass':
        return {'type': 'roughdielectric', 'distribution': 'ggx', 'alpha': p['roughness'] ** 2,
                'int_ior': p['ior'], 'ext_ior': 1.0, 'specular_transmittance': rgb(p['tint'])}
    if kind == 'glossy':
        alpha, eta = p['roughness'] ** 2, p['ior']
        r_int = rough_internal_reflectance(mi, alpha, eta)
        rho = np.array(p['albedo']) * eta * eta * (1 - r_int)
        notes.append(f"glossy: R_int = {r_int:.4f}, roughplastic diffuse_reflectance = "
                     f"{[round(float(c), 4) for c in rho]}, alpha = {alpha:.4f}")
        if rho.max() > 1:
            notes.append("glossy: WARNING diffuse_reflectance > 1 is clamped by Mitsuba")
        return {'type': 'twosided', 'bsdf': {
            'type': 'roughplastic', 'distribution': 'ggx', 'alpha': alpha, 'int_ior': eta,
            'ext_ior': 1.0, 'nonlinear': False, 'diffuse_reflectance': rgb(rho)}}
    if kind == 'layers':
        return {'type': 'blendbsdf', 'weight': p['mask'],
                'bsdf_0': mitsuba_bsdf(mi, p['bottom'], notes), 'bsdf_1': mitsuba_bsdf(mi, p['top'], notes)}
    if kind == 'opacity':
        return {'type': 'mask', 'opacity': p['opacity'], 'bsdf': mitsuba_bsdf(mi, p['bsdf'], notes)}
    if kind == 'thin':
        return {'type': 'thindielectric', 'int_ior': p['ior'], 'ext_ior': 1.0}
    raise ValueError(kind)


def camera_frame(res):
    m = usd_xform(CAMERA['translate'], CAMERA['rotate_xyz'])
    tan_w = CAMERA['aperture'] / 2 / CAMERA['focal']
    return m, tan_w, tan_w * res[1] / res[0]


def quad_matrix(pts):
    """[-1,1]^2 -> the parallelogram p0 p1 p2 p3, local +Z along the winding normal."""
    p = np.array(pts, float)
    u, v = (p[1] - p[0]) / 2, (p[3] - p[0]) / 2
    n = np.cross(u, v)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = u, v, n / np.linalg.norm(n), p.mean(0)
    return m


def mitsuba_scene(mi, sc, res, spp, max_depth, notes, sampler='independent'):
    T = lambda m: mi.ScalarTransform4f(np.asarray(m, float).tolist())
    cam, tan_w, _ = camera_frame(res)
    d = {'type': 'scene',
         'integrator': {'type': 'path', 'max_depth': max_depth + 1},
         'sensor': {'type': 'perspective', 'fov_axis': 'x', 'fov': math.degrees(2 * math.atan(tan_w)),
                    'to_world': T(cam @ np.diag([-1.0, 1, -1, 1])),
                    'film': {'type': 'hdrfilm', 'width': res[0], 'height': res[1], 'pixel_format': 'rgb',
                             'rfilter': {'type': 'box'}},
                    'sampler': {'type': sampler, 'sample_count': spp}},
         'dome': {'type': 'constant', 'radiance': rgb(sc['dome'])}}
    if sc['rect']:
        r = sc['rect']
        m = usd_xform(r['translate'], r['rotate_xyz']) @ scale((r['width'] / 2, r['height'] / 2, 1)) @ rotate('x', 180)
        d['key'] = {'type': 'rectangle', 'to_world': T(m), 'bsdf': {'type': 'null'},
                    'emitter': {'type': 'area', 'radiance': rgb(r['intensity'])}}
    for name, shape, bsdf in sc['objects']:
        b = mitsuba_bsdf(mi, bsdf, notes)
        if shape[0] == 'sphere':
            d[name] = {'type': 'sphere', 'center': list(shape[1]), 'radius': shape[2], 'bsdf': b}
        else:
            d[name] = {'type': 'rectangle', 'to_world': T(quad_matrix(shape[1])), 'bsdf': b}
    return mi.load_dict(d)

# ------------------------------------------------------------------------------------ regions


def regions(sc, res, sub=4):
    """{region name: boolean mask (h, w)}: pixels all of whose sub x sub rays hit the same
    object (for see-through objects: the same object and the same object behind it), eroded by
    one pixel. Ray cast from the scene description with strata's pinhole model."""
    w, h = res
    cam, tan_w, tan_h = camera_frame(res)
    o = cam[:3, 3]
    right, up, fwd = [cam[:3, i] / np.linalg.norm(cam[:3, i]) for i in range(3)]
    fwd = -fwd
    s = (np.arange(sub) + 0.5) / sub
    fx = (np.arange(w)[:, None] + s[None, :]).ravel() / w
    fy = (np.arange(h)[:, None] + s[None, :]).ravel() / h
    X, Y = np.meshgrid(fx, fy)  # (h*sub, w*sub)
    dirs = ((2 * X - 1) * tan_w)[..., None] * right + ((1 - 2 * Y) * tan_h)[..., None] * up + fwd
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    ts = []
    for _, shape, _ in sc['objects']:
        if shape[0] == 'sphere':
            oc = o - np.array(shape[1])
            b = dirs @ oc
            disc = b * b - (oc @ oc - shape[2] ** 2)
            sq = np.sqrt(np.maximum(disc, 0))
            t = np.where(-b - sq > 1e-6, -b - sq, -b + sq)
            t = np.where((disc >= 0) & (t > 1e-6), t, np.inf)
        else:
            p = np.array(shape[1], float)
            u, v = p[1] - p[0], p[3] - p[0]
            n = np.cross(u, v)
            den = dirs @ n
            with np.errstate(divide='ignore', invalid='ignore'):
                t = ((p[0] - o) @ n) / den
            q = o + dirs * t[..., None] - p[0]
            a, c = (q @ u) / (u @ u), (q @ v) / (v @ v)
            t = np.where((t > 1e-6) & (a >= 0) & (a <= 1) & (c >= 0) & (c <= 1), t, np.inf)
        ts.append(t)
    ts = np.stack(ts)  # (objects, H, W)
    first = np.where(np.isinf(ts.min(0)), -1, ts.argmin(0))
    names = [n for n, _, _ in sc['objects']]
    see_through = [b[0] in ('opacity', 'thin') for _, _, b in sc['objects']]
    key = first.copy()
    for i, st in enumerate(see_through):
        if st:  # what is behind the see-through object
            ts2 = ts.copy()
            ts2[i] = np.inf
            behind = np.where(np.isinf(ts2.min(0)), -1, ts2.argmin(0))
            key = np.where(first == i, 1000 * (i + 1) + behind + 1, key)
    k = key.reshape(h, sub, w, sub).transpose(0, 2, 1, 3).reshape(h, w, sub * sub)
    pure = (k == k[..., :1]).all(-1)
    k0 = np.where(pure, k[..., 0], -2)
    out = {}
    for val in np.unique(k0):
        if val == -2:
            continue
        m = k0 == val
        e = m.copy()
        e[1:, :] &= m[:-1, :]; e[:-1, :] &= m[1:, :]
        e[:, 1:] &= m[:, :-1]; e[:, :-1] &= m[:, 1:]
        e[1:, 1:] &= m[:-1, :-1]; e[:-1, :-1] &= m[1:, 1:]
        e[1:, :-1] &= m[:-1, 1:]; e[:-1, 1:] &= m[1:, :-1]
        if val == -1:
            name = 'sky'
        elif val >= 1000:
            i, b = divmod(val, 1000)
            name = f"{names[i - 1]} over {'sky' if b == 0 else names[b - 1]}"
        else:
            name = names[val]
        if e.sum() > 0:
            out[name] = e
    return out

# ------------------------------------------------------------------------------------ renders


def child_cpu(cmd):
    """Run `cmd` to its end: (exit code, user + system CPU seconds of that child alone, from
    os.wait4, wall seconds, stderr). CPU time, not wall time: the machine is shared."""
    with tempfile.TemporaryFile() as err:
        t = time.time()
        p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err)
        _, status, ru = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
        wall = time.time() - t
        err.seek(0)
        return p.returncode, ru.ru_utime + ru.ru_stime, wall, err.read().decode(errors='replace')


def self_cpu():
    """User + system CPU seconds of this process, every thread included (in-process renderers)."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def render_strata(exe, scene, exr, spp, res, max_depth, seed, extra=''):
    cmd = [exe, 'render', os.path.join(ROOT, scene), '-o', exr, '--spp', str(spp),
           '--res', f'{res[0]}x{res[1]}', '--max-depth', str(max_depth), '--seed', str(seed)] + extra.split()
    code, cpu, wall, err = child_cpu(cmd)
    if code != 0:
        sys.exit(f"strata failed: {' '.join(cmd)}\n{err}")
    return (wall, cpu), ' '.join(cmd)


def read_exr_rgb(mi, path):
    bmp = mi.Bitmap(path)
    names = [f.name for f in bmp.struct_()]
    px = np.array(bmp, dtype=np.float64)
    return np.stack([px[..., names.index(c)] for c in 'RGB'], -1)


def render_mitsuba(mi, scene, spp, seed, pass_spp):
    """Average of passes of at most pass_spp samples (bounded JIT memory), and (wall, CPU)
    seconds, which include the kernel compilation of the first pass."""
    acc, done, k = None, 0, 0
    t, c = time.time(), time.process_time()
    while done < spp:
        n = min(pass_spp, spp - done)
        img = np.array(mi.render(scene, spp=n, seed=seed * 100_003 + k), dtype=np.float64) * n
        acc = img if acc is None else acc + img
        done += n
        k += 1
    return acc / spp, (time.time() - t, time.process_time() - c)

# ------------------------------------------------------------------------------------ metrics


def flip_map(ref, test):
    try:
        import flip_evaluator as flip
    except ImportError:
        return None
    err, _, _ = flip.evaluate(np.ascontiguousarray(ref, np.float32), np.ascontiguousarray(test, np.float32),
                              'HDR', applyMagma=False)
    return np.asarray(err, np.float64).reshape(ref.shape[:2])


def region_figures(s, s2, m, m2, fl, fl_ss, fl_mm, mask):
    """Figures of one region; `s2`, `m2` are the second renders (other seeds) that give the noise
    floors: what the strata-Mitsuba figure would be if the two differed by noise alone."""
    L = lambda img: luminance(img)[mask]
    ls, ls2, lm, lm2 = L(s), L(s2), L(m), L(m2)
    mean_m = lm.mean()
    d = ls - lm
    ch = [(s[..., c][mask].mean() - m[..., c][mask].mean()) / max(m[..., c][mask].mean(), 1e-12) for c in range(3)]
    mae_ss, mae_mm = np.abs(ls2 - ls).mean() / mean_m, np.abs(lm2 - lm).mean() / mean_m
    nan = float('nan')
    f_ss = fl_ss[mask].mean() if fl_ss is not None else nan
    f_mm = fl_mm[mask].mean() if fl_mm is not None else nan
    return dict(pixels=int(mask.sum()), mean_strata=ls.mean(), mean_mitsuba=mean_m,
                rel_diff=d.mean() / mean_m, rel_diff_2se=2 * d.std(ddof=1) / math.sqrt(d.size) / mean_m,
                rel_diff_r=ch[0], rel_diff_g=ch[1], rel_diff_b=ch[2], worst_channel=max(ch, key=abs),
                rel_mae=np.abs(d).mean() / mean_m, rel_mae_ss=mae_ss, rel_mae_mm=mae_mm,
                rel_mae_noise=math.sqrt((mae_ss ** 2 + mae_mm ** 2) / 2),
                flip=fl[mask].mean() if fl is not None else nan, flip_ss=f_ss, flip_mm=f_mm,
                flip_noise=math.sqrt((f_ss ** 2 + f_mm ** 2) / 2))


def pct(x):
    return f"{100 * x:+6.2f} %"


def load_mitsuba(variant, threads=None):
    """Mitsuba with `variant` (scalar_rgb, with a note on stderr, when the variant cannot load,
    e.g. llvm_ad_rgb without libLLVM) and, if given, that many worker threads."""
    if 'DRJIT_LIBLLVM_PATH' not in os.environ:
        import glob
        libs = sorted(glob.glob('/usr/lib/x86_64-linux-gnu/libLLVM-[0-9]*.so*'),
                      key=lambda f: [int(v) for v in f.split('libLLVM-')[1].split('.so')[0].split('.') if v.isdigit()])
        if libs:
            os.environ['DRJIT_LIBLLVM_PATH'] = libs[-1]
    import mitsuba as mi
    try:
        mi.set_variant(variant)
    except Exception as e:
        print(f"variant {variant} unavailable ({e}); using scalar_rgb", file=sys.stderr)
        mi.set_variant('scalar_rgb')
    if threads:
        import drjit as dr
        dr.set_thread_count(threads)
    return mi


def images(args):
    mi = load_mitsuba(args.variant)
    res = tuple(int(v) for v in args.res.split('x'))
    exe = os.path.join(ROOT, args.strata)
    os.makedirs(args.out, exist_ok=True)
    rows = []
    print(f"strata vs Mitsuba {mi.__version__} ({mi.variant()}): {res[0]}x{res[1]}, {args.spp} spp, "
          f"box filter, strata --max-depth {args.max_depth} = Mitsuba max_depth {args.max_depth + 1}")
    for name in args.scenes.split(','):
        sc = SCENES[name]
        notes = []
        exr = os.path.join(args.out, f'{name}_strata.exr')
        ts, cmd = render_strata(exe, sc['usda'], exr, args.spp, res, args.max_depth, args.seed, args.strata_args)
        exr2 = os.path.join(args.out, f'{name}_strata_seed2.exr')
        render_strata(exe, sc['usda'], exr2, args.spp, res, args.max_depth, args.seed + 1, args.strata_args)
        s, s2 = read_exr_rgb(mi, exr), read_exr_rgb(mi, exr2)
        scene = mitsuba_scene(mi, sc, res, args.spp, args.max_depth, notes)
        m, tm = render_mitsuba(mi, scene, args.spp, args.seed, args.pass_spp)
        m2, tm2 = render_mitsuba(mi, scene, args.spp, args.seed + 1, args.pass_spp)
        fl, fl_ss, fl_mm = flip_map(m, s), flip_map(s, s2), flip_map(m, m2)
        for img, suffix in ((m, 'mitsuba'), (m2, 'mitsuba_seed2')):
            mi.Bitmap(img.astype(np.float32)).write(os.path.join(args.out, f'{name}_{suffix}.exr'))
        side = np.concatenate([s, m] + ([np.repeat(fl[..., None], 3, -1)] if fl is not None else []), 1)
        mi.util.write_bitmap(os.path.join(args.out, f'{name}_strata_mitsuba_flip.png'), side.astype(np.float32))
        regs = regions(sc, res)
        regs['image'] = np.ones(res[::-1], bool)
        print(f"\n{name}: {sc['usda']}   wall / CPU seconds: strata {ts[0]:.1f} / {ts[1]:.1f}, "
              f"Mitsuba {tm[0]:.1f} / {tm[1]:.1f} (with its JIT compilation), {tm2[0]:.1f} / {tm2[1]:.1f} (cached)")
        print(f"  {cmd}")
        for n in notes:
            print(f"  {n}")
        print(f"  {'region':<18}{'pixels':>7}  {'strata':>8} {'Mitsuba':>8}  {'mean diff ± 2se':>18}  "
              f"{'worst ch':>9}  {'rel MAE (noise)':>16}  {'FLIP (noise)':>14}")
        for rn, mask in regs.items():
            if rn == 'sky':
                continue
            f = region_figures(s, s2, m, m2, fl, fl_ss, fl_mm, mask)
            print(f"  {rn:<18}{f['pixels']:>7}  {f['mean_strata']:8.4f} {f['mean_mitsuba']:8.4f}  "
                  f"{pct(f['rel_diff'])} ± {100 * f['rel_diff_2se']:4.2f}  {pct(f['worst_channel'])}  "
                  f"{100 * f['rel_mae']:6.2f} ({100 * f['rel_mae_noise']:5.2f}) %  "
                  f"{f['flip']:.4f} ({f['flip_noise']:.4f})")
            rows.append(dict(scene=name, region=rn, res=f'{res[0]}x{res[1]}', spp=args.spp,
                             max_depth=args.max_depth, strata_wall_s=round(ts[0], 2), strata_cpu_s=round(ts[1], 2),
                             mitsuba_wall_s=round(tm2[0], 2), mitsuba_cpu_s=round(tm2[1], 2),
                             **{k: (round(v, 5) if isinstance(v, float) else v) for k, v in f.items()}))
    if args.csv:
        with open(args.csv, 'w', newline='') as fh:
            wr = csv.DictWriter(fh, fieldnames=list(rows[0].keys()))
            wr.writeheader()
            wr.writerows(rows)
        print(f"\nwrote {args.csv}")


# ------------------------------------------------------------------------------- CI check

# Model tolerance per region, relative to Mitsuba's mean, on top of the noise bound: where the
# two renderers' models differ by design. Only the coat does: strata's `glossy` weights its
# Lambert base by smooth-interface (1 - F(mu_i))(1 - F(mu_o)), roughplastic by rough-interface
# transmittances with internal re-scattering (`coat` integrates both under uniform light:
# strata 0.1-0.4 % darker for cos theta_o >= 0.4, 3 % at 0.2 and 9 % at 0.1; the region,
# whose eroded rim leaves out the grazing pixels, measured -0.19 % +- 0.11 at 320x240, 1024
# spp). 1 % bounds that model difference with room for the region's changing share of rim
# pixels at other resolutions, and is still 10x below the 10 % albedo error CI must catch.
MODEL_TOLERANCE = {('mcg', 'coated'): 0.01}


def region_agreement(name, sc, res, s, m, sigmas, min_pixels, tolerance=None):
    """Per object region of scene `name` (sky and regions under `min_pixels` left out): the
    means of the luminances of two-seed pairs `s` (strata) and `m` (the other renderer), their
    difference, its standard error, the region's model tolerance and whether |diff| <= sigmas
    se + tolerance x mean_m. Pixels are independent (each renderer's streams are per pixel),
    so the variance of a region's mean of a two-render average is sum over pixels of
    (a - b)^2 / 4, over pixels^2, and the two renderers' add."""
    tolerance = MODEL_TOLERANCE if tolerance is None else tolerance
    rows = []
    for rn, mask in regions(sc, res).items():
        n = int(mask.sum())
        if rn == 'sky' or n < min_pixels:
            continue
        mean_s, mean_m = [float(((a + b) / 2)[mask].mean()) for a, b in (s, m)]
        var = sum(float((((a - b) ** 2) / 4)[mask].sum()) for a, b in (s, m)) / (n * n)
        se = math.sqrt(var)
        tol = tolerance.get((name, rn), 0.0)
        diff = mean_s - mean_m
        rows.append(dict(region=rn, pixels=n, mean_s=mean_s, mean_m=mean_m, diff=diff, se=se, tol=tol,
                         ok=abs(diff) <= sigmas * se + tol * abs(mean_m)))
    return rows


def check(args):
    """CI: per region, |mean strata - mean Mitsuba| <= sigmas x standard error + the region's
    model tolerance (MODEL_TOLERANCE) x mean Mitsuba, on the luminance of each renderer's
    average of two renders with different seeds (standard error from the renders themselves:
    region_agreement). Exit status 1 when any region fails."""
    import mitsuba as mi
    mi.set_variant(args.variant)
    res = tuple(int(v) for v in args.res.split('x'))
    exe = os.path.join(ROOT, args.strata)
    os.makedirs(args.out, exist_ok=True)
    seeds = (args.seed, args.seed + 1)
    print(f"strata vs Mitsuba {mi.__version__} ({mi.variant()}): {res[0]}x{res[1]}, {args.spp} spp x 2 seeds, "
          f"strata --max-depth {args.max_depth} = Mitsuba max_depth {args.max_depth + 1}; pass: "
          f"|diff| <= {args.sigmas:g} se + model tolerance")
    failed, t0 = [], time.time()
    for name in args.scenes.split(','):
        sc, notes = SCENES[name], []
        s = []
        for seed in seeds:
            exr = os.path.join(args.out, f'{name}_strata_{seed}.exr')
            render_strata(exe, sc['usda'], exr, args.spp, res, args.max_depth, seed, args.strata_args)
            s.append(luminance(read_exr_rgb(mi, exr)))
        scene = mitsuba_scene(mi, sc, res, args.spp, args.max_depth, notes)
        m = [luminance(np.array(mi.render(scene, spp=args.spp, seed=seed), dtype=np.float64)) for seed in seeds]
        print(f"\n{name}: {sc['usda']}")
        print(f"  {'region':<18}{'pixels':>7}  {'strata':>8} {'Mitsuba':>8}  {'diff':>8}  {'se':>6}  "
              f"{'z':>6}  {'model tol':>9}  verdict")
        for r in region_agreement(name, sc, res, s, m, args.sigmas, args.min_pixels):
            if not r['ok']:
                failed.append(f"{name}/{r['region']}")
            print(f"  {r['region']:<18}{r['pixels']:>7}  {r['mean_s']:8.4f} {r['mean_m']:8.4f}  "
                  f"{pct(r['diff'] / r['mean_m'])}  {100 * r['se'] / r['mean_m']:4.2f} %"
                  f"  {r['diff'] / r['se'] if r['se'] > 0 else 0.0:+6.2f}  {100 * r['tol']:7.1f} %  {'ok' if r['ok'] else 'FAIL'}")
    print(f"\n{time.time() - t0:.0f} s")
    if failed:
        sys.exit(f"strata differs from Mitsuba beyond noise and model tolerance in: {', '.join(failed)}")
    print("strata matches Mitsuba within noise in every region")


def timing(args):
    """docs/PERFORMANCE.md's figure: the matte ball at 640x480, 64 spp, three runs (the first
    includes kernel compilation). Compare with
        strata render scenes/compare/matte_ball.usda -o strata.exr --spp 64 --max-depth 8"""
    mi = load_mitsuba(args.variant)
    notes = []
    scene = mitsuba_scene(mi, SCENES['matte'], (640, 480), 64, 8, notes)
    for k in range(3):
        t = time.time()
        img = mi.render(scene, spp=64, seed=k)
        np.array(img)  # force evaluation
        print(f"run {k}: {time.time() - t:.2f} s")



# --------------------------------------------------------------------- equal-error measurement


def two_seed_variance(a, b):
    """Variance of one render's pixel values, from two renders with different seeds: mean over
    pixels (and channels) of (a - b)^2 / 2. Times spp: variance per sample per pixel."""
    return float(np.mean((a - b) ** 2) / 2)


def machine_line():
    """CPU model, core count and load average: printed with every measured table."""
    model, flags = 'unknown CPU', []
    try:
        with open('/proc/cpuinfo') as fh:
            info = fh.read().splitlines()
        model = next(l.split(':', 1)[1].strip() for l in info if l.startswith('model name'))
        have = next(l.split(':', 1)[1].split() for l in info if l.startswith('flags'))
        flags = [f for f in ('avx2', 'fma', 'avx512f') if f in have]
    except (OSError, StopIteration):
        pass
    return f"{model} ({' '.join(flags) or 'no AVX2'}), {os.cpu_count()} cores, load average {' / '.join(f'{v:.2f}' for v in os.getloadavg())} (1/5/15 min)"


def strata_rev():
    p = subprocess.run(['git', '-C', ROOT, 'log', '-1', '--format=%h %cd', '--date=short'], capture_output=True, text=True)
    return p.stdout.strip() or 'unknown'


def strata_pair(exe, sc, out, name, res, spp, max_depth, seeds, extra):
    """strata's two-seed renders at `spp` (RGB images, CPU seconds each) and the CPU seconds of
    a 1-spp render: what the process costs besides its samples (parse, compile, BVH, writing)."""
    imgs, cpus = [], []
    for seed in seeds:
        exr = os.path.join(out, f'{name}_strata_{spp}spp_{seed}.exr')
        (_, cpu), _ = render_strata(exe, sc['usda'], exr, spp, res, max_depth, seed, extra)
        imgs.append(read_exr(exr))
        cpus.append(cpu)
    exr = os.path.join(out, f'{name}_strata_1spp.exr')
    (_, cpu1), _ = render_strata(exe, sc['usda'], exr, 1, res, max_depth, seeds[0], extra)
    return imgs, cpus, cpu1


def mitsuba_pair(mi, scene, spp, seeds):
    """Mitsuba's two-seed renders at `spp` and the CPU seconds of each (this process, every
    thread), and of a 1-spp render. Each render is run twice and the second is timed, so JIT
    kernels are compiled and cached before the clock runs (as a farm's would be)."""
    def timed(n, seed):
        for _ in range(2):
            c = self_cpu()
            img = np.array(mi.render(scene, spp=n, seed=seed), dtype=np.float64)
            cpu = self_cpu() - c
        return img, cpu
    pairs = [timed(spp, seed) for seed in seeds]
    return [p[0] for p in pairs], [p[1] for p in pairs], timed(1, seeds[0])[1]


def equal_error_row(sc, name, res, spp, strata, other, sigmas=3.0, min_pixels=16, tolerance=None):
    """The measured figures of one scene from (images, CPU seconds, 1-spp CPU seconds) of
    strata and of the other renderer: CPU seconds per spp (the 1-spp render's cost taken off:
    what each more sample costs), variance per spp by the two-seed method over the whole image
    and per region, equal-error time = time-per-spp ratio x variance-per-spp ratio, and the
    agreement of the two mean images (whole image and per region, region_agreement)."""
    (s_img, s_cpu, s_cpu1), (o_img, o_cpu, o_cpu1) = strata, other
    tps_s = (np.mean(s_cpu) - s_cpu1) / (spp - 1)
    tps_o = (np.mean(o_cpu) - o_cpu1) / (spp - 1)
    var_s, var_o = two_seed_variance(*s_img) * spp, two_seed_variance(*o_img) * spp
    ls, lo = [luminance(i) for i in s_img], [luminance(i) for i in o_img]
    mean_s, mean_o = float(np.mean(ls)), float(np.mean(lo))
    n = ls[0].size
    se = math.sqrt(sum(float(((a - b) ** 2 / 4).sum()) for a, b in (ls, lo))) / n
    regs = region_agreement(name, sc, res, ls, lo, sigmas, min_pixels, tolerance)
    by_region = {}
    for rn, mask in regions(sc, res).items():
        if rn != 'sky' and mask.sum() >= min_pixels:
            vo = two_seed_variance(o_img[0][mask], o_img[1][mask])
            by_region[rn] = two_seed_variance(s_img[0][mask], s_img[1][mask]) / vo if vo > 0 else float('nan')
    worst = max(by_region, key=lambda k: by_region[k]) if by_region else ''
    return dict(scene=name, res=f'{res[0]}x{res[1]}', spp=spp,
                strata_cpu_s=' '.join(f'{c:.3f}' for c in s_cpu), strata_cpu_1spp_s=round(s_cpu1, 3),
                other_cpu_s=' '.join(f'{c:.3f}' for c in o_cpu), other_cpu_1spp_s=round(o_cpu1, 3),
                strata_ms_per_spp=1e3 * tps_s, other_ms_per_spp=1e3 * tps_o, time_ratio=tps_s / tps_o,
                strata_var_per_spp=var_s, other_var_per_spp=var_o, var_ratio=var_s / var_o,
                equal_error_ratio=tps_s / tps_o * var_s / var_o,
                worst_region=worst, worst_region_var_ratio=by_region.get(worst, float('nan')),
                region_var_ratios=' '.join(f'{k}={v:.3f}' for k, v in by_region.items()),
                mean_strata=mean_s, mean_other=mean_o, mean_rel_diff=(mean_s - mean_o) / mean_o,
                mean_rel_se=se / mean_o,
                regions_ok=sum(r['ok'] for r in regs), regions=len(regs),
                regions_failed=' '.join(r['region'] for r in regs if not r['ok']),
                worst_region_z=max((abs(r['diff']) / r['se'] for r in regs), default=0.0))


def equal_error_table(rows, other):
    """The docs/PERFORMANCE.md table of equal_error_row rows, markdown."""
    out = [f"| scene | CPU ms per spp, strata / {other} | time per spp | variance per spp (worst region) | "
           f"**equal-error time** | image mean, strata vs {other} (± 3 se) | regions within 3 se + tol |",
           "|---|---|---|---|---|---|---|"]
    for r in rows:
        worst = (f" ({r['worst_region']} {r['worst_region_var_ratio']:.2f})"
                 if r['worst_region'] and abs(r['worst_region_var_ratio'] - r['var_ratio']) > 0.1 else '')
        out.append(f"| {r['scene']} | {r['strata_ms_per_spp']:.1f} / {r['other_ms_per_spp']:.1f} | "
                   f"{r['time_ratio']:.2f}x | {r['var_ratio']:.2f}{worst} | **{r['equal_error_ratio']:.2f}x** | "
                   f"{100 * r['mean_rel_diff']:+.2f} % ± {300 * r['mean_rel_se']:.2f} | "
                   f"{r['regions_ok']}/{r['regions']}{' (' + r['regions_failed'] + ')' if r['regions_failed'] else ''} |")
    return '\n'.join(out)


def write_csv(path, rows, extra):
    """rows (dicts) to `path`, each with the `extra` columns (renderer versions, machine)."""
    rows = [{**r, **extra} for r in rows]
    with open(path, 'w', newline='') as fh:
        wr = csv.DictWriter(fh, fieldnames=list(rows[0].keys()))
        wr.writeheader()
        for r in rows:
            wr.writerow({k: (f'{v:.6g}' if isinstance(v, float) else v) for k, v in r.items()})


def measure(args):
    """Equal-error CPU time, strata / Mitsuba, per comparison scene (issue 27): both renderers at
    the same resolution, thread count and spp, two seeds each; see equal_error_row."""
    mi = load_mitsuba(args.variant, args.threads)
    res = tuple(int(v) for v in args.res.split('x'))
    exe = os.path.join(ROOT, args.strata)
    os.makedirs(args.out, exist_ok=True)
    seeds = (args.seed, args.seed + 1)
    extra = f'--threads {args.threads} {args.strata_args}'.strip()
    t0, machine0 = time.time(), machine_line()
    rows = []
    for name in args.scenes.split(','):
        sc = SCENES[name]
        strata = strata_pair(exe, sc, args.out, name, res, args.spp, args.max_depth, seeds, extra)
        scene = mitsuba_scene(mi, sc, res, args.spp, args.max_depth, [], args.mitsuba_sampler)
        rows.append(equal_error_row(sc, name, res, args.spp, strata, mitsuba_pair(mi, scene, args.spp, seeds)))
        print(f"{name}: {rows[-1]['equal_error_ratio']:.2f}x ({time.time() - t0:.0f} s)", file=sys.stderr)
    head = (f"strata ({strata_rev()}) vs Mitsuba {mi.__version__} `{mi.variant()}` ({args.mitsuba_sampler} sampler), "
            f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC: {res[0]}x{res[1]}, "
            f"{args.spp} spp x seeds {seeds[0]} and {seeds[1]}, {args.threads} threads, box filter, "
            f"strata --max-depth {args.max_depth} = Mitsuba max_depth {args.max_depth + 1}; CPU time (user + sys)\n"
            f"machine: {machine0} at the start, {os.getloadavg()[0]:.2f} at the end; {time.time() - t0:.0f} s\n"
            f"command: {' '.join(['tools/compare_mitsuba.py'] + sys.argv[1:])}")
    print(head + '\n\n' + equal_error_table(rows, 'Mitsuba'))
    if args.csv:
        write_csv(args.csv, rows, dict(other=f'mitsuba {mi.__version__} {mi.variant()} {args.mitsuba_sampler}', threads=args.threads,
                                       strata=strata_rev(), machine=machine0))
        print(f"\nwrote {args.csv}")


def read_exr(path):
    """The RGB of an EXR as float64 (h, w, 3), through OpenEXR (tools/rmse.py) or Mitsuba."""
    try:
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        from rmse import load
        return load(path)
    except ImportError:
        import mitsuba as mi
        return read_exr_rgb(mi, path)


def coat(args):
    """Directional albedo of strata's glossy BSDF (a numpy transcription of bsdf.rs) against the
    roughplastic it is mapped to, by quadrature under uniform white light: the size of the
    model difference alone, for the `coated` region of scene mcg."""
    mi = load_mitsuba(args.variant)
    import drjit as dr
    kind, p = next(b for n, _, b in SCENES['mcg']['objects'] if n == 'coated')
    albedo, alpha, eta = np.array(p['albedo']), p['roughness'] ** 2, p['ior']
    notes = []
    rp = mi.load_dict(mitsuba_bsdf(mi, (kind, p), notes)['bsdf'])
    print(f"strata glossy(albedo {p['albedo']}, roughness {p['roughness']}, ior {eta}) vs roughplastic "
          f"({notes[0].split(': ', 1)[1]}); luminance of the directional albedo:")
    x, w = np.polynomial.legendre.leggauss(256)
    nphi = 256
    mu, phi = np.meshgrid((x + 1) / 2, (np.arange(nphi) + 0.5) * 2 * np.pi / nphi, indexing='ij')
    weight = (np.broadcast_to(w[:, None] / 2, mu.shape) * 2 * np.pi / nphi).ravel()
    st = np.sqrt(1 - mu * mu)
    wi = np.stack([st * np.cos(phi), st * np.sin(phi), mu], -1).reshape(-1, 3)

    def fresnel(c, eta):
        s2 = (1 - c * c) / (eta * eta)
        ct = np.sqrt(np.maximum(0, 1 - s2))
        rs, rp_ = (c - eta * ct) / (c + eta * ct), (eta * c - ct) / (eta * c + ct)
        return np.where(s2 >= 1, 1.0, 0.5 * (rs * rs + rp_ * rp_))

    def lam(v):
        t = alpha ** 2 * (v[..., 0] ** 2 + v[..., 1] ** 2) / v[..., 2] ** 2
        return t / (2 * (np.sqrt(1 + t) + 1))

    lum = np.array([0.2126, 0.7152, 0.0722])
    print(f"  {'cos theta_o':>11}  {'strata':>8} {'Mitsuba':>8}  strata/Mitsuba - 1")
    for mu_o in (1.0, 0.8, 0.6, 0.4, 0.3, 0.2, 0.1):
        wo = np.array([math.sqrt(1 - mu_o ** 2), 0, mu_o])
        m = wo + wi
        m /= np.linalg.norm(m, axis=-1, keepdims=True)
        t = m[:, 0] ** 2 + m[:, 1] ** 2 + alpha ** 2 * m[:, 2] ** 2
        d = alpha ** 2 / np.pi / (t * t)
        spec = d / (1 + lam(wo) + lam(wi)) * fresnel(m @ wo, eta) / (4 * wo[2] * wi[:, 2])
        base = albedo / np.pi * ((1 - fresnel(wo[2], eta)) * (1 - fresnel(wi[:, 2], eta)))[:, None]
        a_s = ((base + spec[:, None]) * (wi[:, 2] * weight)[:, None]).sum(0) @ lum
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi = mi.Vector3f(*[float(c) for c in wo])
        si.sh_frame = mi.Frame3f(mi.Normal3f(0, 0, 1))
        f = rp.eval(mi.BSDFContext(), si, mi.Vector3f(*[mi.Float(wi[:, k].astype(np.float32)) for k in range(3)]))
        f = np.array(f).reshape(-1, 3) if np.array(f).shape[-1] == 3 else np.array(f).T
        a_m = (f * weight[:, None]).sum(0) @ lum
        print(f"  {mu_o:11.1f}  {a_s:8.4f} {a_m:8.4f}  {pct(a_s / a_m - 1)}")


def render_options(p, scenes, spp, res, max_depth, variant, out):
    """The options every rendering subcommand takes, with that subcommand's defaults."""
    p.add_argument('--scenes', default=scenes)
    p.add_argument('--spp', type=int, default=spp)
    p.add_argument('--res', default=res)
    p.add_argument('--max-depth', type=int, default=max_depth)
    p.add_argument('--seed', type=int, default=1)
    p.add_argument('--variant', default=variant)
    p.add_argument('--strata', default='target/release/strata')
    p.add_argument('--out', default=out)
    p.add_argument('--strata-args', default='', help='extra strata render flags, e.g. --weighted')


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    sub = ap.add_subparsers(dest='cmd', required=True)
    a = sub.add_parser('images')
    render_options(a, 'matte,mcg,layers_dome,layers,thin', 1024, '320x240', 16, 'llvm_ad_rgb', '/tmp/strata_vs_mitsuba')
    a.add_argument('--pass-spp', type=int, default=64, help='Mitsuba samples per render call')
    a.add_argument('--csv', default=None)
    c = sub.add_parser('check', help='CI: fail when a region differs beyond noise and model tolerance')
    render_options(c, 'matte,mcg,layers_dome,layers,thin', 128, '128x96', 8, 'scalar_rgb', 'target/mitsuba_check')
    c.add_argument('--sigmas', type=float, default=3.0)
    c.add_argument('--min-pixels', type=int, default=16)
    e = sub.add_parser('measure', help='equal-error CPU time, strata / Mitsuba, by the two-seed method')
    render_options(e, 'matte,mcg,layers,layers_dome', 64, '320x240', 8, 'llvm_ad_rgb', '/tmp/strata_vs_mitsuba_measure')
    e.add_argument('--threads', type=int, default=2)
    e.add_argument('--mitsuba-sampler', default='independent', help="Mitsuba's sampler (its default: independent)")
    e.add_argument('--csv', default=None)
    for name in ('timing', 'coat'):
        sub.add_parser(name).add_argument('--variant', default='llvm_ad_rgb')
    args = ap.parse_args()
    {'images': images, 'check': check, 'measure': measure, 'timing': timing, 'coat': coat}[args.cmd](args)


if __name__ == '__main__':
    main()
