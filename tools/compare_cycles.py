"""strata against Cycles (Blender's path tracer, the `bpy` module from PyPI): the matte ball of
scenes/compare/matte_ball.usda built natively in bpy, measured as tools/compare_mitsuba.py
measures against Mitsuba (issue 27). Optional tool: neither `cargo test` nor CI needs it.

    python3 -m venv venv && venv/bin/pip install bpy numpy OpenEXR mitsuba==3.9.1
    cargo build --release
    venv/bin/python tools/compare_cycles.py measure [--res 320x240] [--spp 64] [--threads 2]
        [--csv FILE]           # equal-error CPU time, strata / Cycles, after the images agree
    venv/bin/python tools/compare_cycles.py throughput [--res 640x480] [--spp 64]
                               # one thread: samples per CPU second, strata / Mitsuba / Cycles

The scene in Cycles, as strata renders the .usda:
  camera   location (0, 1.4, 6.5), Euler XYZ (-5.27, 0, 0) degrees (UsdGeom's rotateXYZ is the
           same matrix, T Rz Ry Rx), 35 mm lens on a 36 mm sensor fitted horizontally; Blender's
           camera looks down local -Z like UsdGeom's. The scene keeps USD's Y up: no axis swap.
  dome     the world's Background, white, strength 1 (a constant environment of radiance 1).
  floor    a quad (-6..6)^2 at y = 0, Diffuse BSDF 0.5; the ball: radius 0.8 at (0, 0.8, 0),
           Diffuse BSDF 0.8, an analytic sphere (a point cloud of one point, which Cycles
           intersects as a sphere; strata's Sphere prim is analytic too).
  film     box filter 1 px, no denoising, no adaptive sampling, no clamping, no light threshold,
           no glossy filter; max_bounces = strata's --max-depth - 1 (Cycles counts bounces
           after the camera hit, strata path segments as Mitsuba's max_depth - 1 does); the
           default sampling pattern. The render is read from a 32-bit EXR (scene linear).

Cycles renders in a child process (`_cycles` below) so that bpy and Mitsuba never share one;
it times each render by its own CPU clock (every thread), like Mitsuba's in-process renders.
"""
import argparse
import datetime
import json
import os
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import compare_mitsuba as cm  # noqa: E402  (tools/: the scenes, timing and figures)

# Regions are given no model tolerance: the scene is the same in both renderers.
CYCLES_TOLERANCE = {}


def build_cycles_scene(bpy, res, spp, max_depth, threads, seed):
    """The matte ball (cm.SCENES['matte']) as a fresh bpy scene; see the module docstring."""
    import math
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    sc = cm.SCENES['matte']
    scene.render.engine = 'CYCLES'
    cy = scene.cycles
    cy.device = 'CPU'
    cy.samples = spp
    cy.seed = seed
    cy.use_animated_seed = False
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    cy.pixel_filter_type = 'BOX'
    cy.filter_width = 1.0
    cy.sample_clamp_direct = 0.0
    cy.sample_clamp_indirect = 0.0
    cy.light_sampling_threshold = 0.0
    cy.blur_glossy = 0.0
    cy.max_bounces = cy.diffuse_bounces = cy.glossy_bounces = cy.transmission_bounces = max_depth - 1
    cy.transparent_max_bounces = max_depth - 1
    cy.caustics_reflective = cy.caustics_refractive = True
    scene.render.threads_mode = 'FIXED'
    scene.render.threads = threads
    scene.render.resolution_x, scene.render.resolution_y = res
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1
    scene.render.film_transparent = False
    scene.view_settings.view_transform = 'Standard'
    scene.view_settings.look = 'None'
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    img = scene.render.image_settings
    img.file_format = 'OPEN_EXR'
    img.color_mode = 'RGB'
    img.color_depth = '32'
    img.exr_codec = 'NONE'

    world = bpy.data.worlds.new('dome')
    world.use_nodes = True
    bg = world.node_tree.nodes['Background']
    bg.inputs['Color'].default_value = (sc['dome'],) * 3 + (1.0,)
    bg.inputs['Strength'].default_value = 1.0
    scene.world = world

    cam_data = bpy.data.cameras.new('camera')
    cam_data.lens = cm.CAMERA['focal']
    cam_data.sensor_width = cm.CAMERA['aperture']
    cam_data.sensor_fit = 'HORIZONTAL'
    cam_data.clip_start, cam_data.clip_end = 1e-3, 1e4
    cam = bpy.data.objects.new('camera', cam_data)
    cam.location = cm.CAMERA['translate']
    cam.rotation_mode = 'XYZ'
    cam.rotation_euler = [math.radians(a) for a in cm.CAMERA['rotate_xyz']]
    scene.collection.objects.link(cam)
    scene.camera = cam

    def diffuse(name, albedo):
        mat = bpy.data.materials.new(name)
        mat.use_nodes = True
        nodes = mat.node_tree.nodes
        nodes.clear()
        d = nodes.new('ShaderNodeBsdfDiffuse')
        d.inputs['Color'].default_value = (albedo,) * 3 + (1.0,)
        d.inputs['Roughness'].default_value = 0.0
        out = nodes.new('ShaderNodeOutputMaterial')
        mat.node_tree.links.new(d.outputs['BSDF'], out.inputs['Surface'])
        return mat

    for name, shape, (kind, p) in sc['objects']:
        assert kind == 'diffuse'
        mat = diffuse(name, p['albedo'])
        if shape[0] == 'quad':
            mesh = bpy.data.meshes.new(name)
            mesh.from_pydata([tuple(v) for v in shape[1]], [], [(0, 1, 2, 3)])
            mesh.materials.append(mat)
            obj = bpy.data.objects.new(name, mesh)
        else:
            obj = point_sphere(bpy, name, shape[1], shape[2], mat)
        scene.collection.objects.link(obj)
    return scene


def point_sphere(bpy, name, center, radius, mat):
    """An analytic sphere in Cycles: a point cloud of one point, made by geometry nodes from a
    one-vertex mesh (Mesh to Points with the radius, Set Material)."""
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(center)], [], [])
    obj = bpy.data.objects.new(name, mesh)
    ng = bpy.data.node_groups.new(name, 'GeometryNodeTree')
    ng.interface.new_socket('Geometry', in_out='INPUT', socket_type='NodeSocketGeometry')
    ng.interface.new_socket('Geometry', in_out='OUTPUT', socket_type='NodeSocketGeometry')
    gin, gout = ng.nodes.new('NodeGroupInput'), ng.nodes.new('NodeGroupOutput')
    pts = ng.nodes.new('GeometryNodeMeshToPoints')
    pts.inputs['Radius'].default_value = radius
    setmat = ng.nodes.new('GeometryNodeSetMaterial')
    setmat.inputs['Material'].default_value = mat
    ng.links.new(gin.outputs[0], pts.inputs['Mesh'])
    ng.links.new(pts.outputs['Points'], setmat.inputs['Geometry'])
    ng.links.new(setmat.outputs['Geometry'], gout.inputs[0])
    obj.modifiers.new('points', 'NODES').node_group = ng
    return obj


def cycles_worker(args):
    """Child process: render each (spp, seed) of --jobs, each twice (the second timed: scene
    sync and kernel set-up done; once with --untimed), write EXRs and print one JSON line per job."""
    import bpy
    res = tuple(int(v) for v in args.res.split('x'))
    for job in args.jobs.split(','):
        spp, seed = (int(v) for v in job.split(':'))
        scene = build_cycles_scene(bpy, res, spp, args.max_depth, args.threads, seed)
        path = os.path.join(args.out, f'matte_cycles_{spp}spp_{seed}.exr')
        scene.render.filepath = path
        for _ in range(1 if args.untimed else 2):
            c = cm.self_cpu()
            bpy.ops.render.render(write_still=True)
            cpu = cm.self_cpu() - c
        print(json.dumps(dict(spp=spp, seed=seed, exr=path, cpu=cpu, version=bpy.app.version_string,
                              pattern=scene.cycles.sampling_pattern)), flush=True)


def cycles_renders(res, jobs, max_depth, threads, out, timed=True):
    """Run the Cycles child for `jobs` [(spp, seed)]: {(spp, seed): (RGB image, CPU s)}, version,
    sampling pattern. Untimed: each job rendered once (its CPU seconds then include set-up)."""
    cmd = [sys.executable, os.path.abspath(__file__), '_cycles', '--res', f'{res[0]}x{res[1]}',
           '--jobs', ','.join(f'{s}:{seed}' for s, seed in jobs), '--max-depth', str(max_depth),
           '--threads', str(threads), '--out', out] + ([] if timed else ['--untimed'])
    p = subprocess.run(cmd, capture_output=True, text=True)
    lines = [json.loads(l) for l in p.stdout.splitlines() if l.startswith('{')]
    if p.returncode != 0 or len(lines) != len(jobs):
        sys.exit(f"Cycles failed: {' '.join(cmd)}\n{p.stderr[-3000:]}")
    got = {(j['spp'], j['seed']): (cm.read_exr(j['exr']), j['cpu']) for j in lines}
    return got, lines[0]['version'], lines[0]['pattern']


def cycles_pair(res, spp, max_depth, threads, seeds, out):
    """Cycles' counterpart of cm.strata_pair: two-seed images, their CPU seconds, 1-spp CPU."""
    got, version, pattern = cycles_renders(res, [(spp, s) for s in seeds] + [(1, seeds[0])], max_depth, threads, out)
    return ([got[(spp, s)][0] for s in seeds], [got[(spp, s)][1] for s in seeds], got[(1, seeds[0])][1]), version, pattern


def measure(args):
    """Equal-error CPU time, strata / Cycles, on the matte ball; refuses to quote ratios when
    the mean images differ by more than --agree (relative, whole image) plus 3 standard errors."""
    res = tuple(int(v) for v in args.res.split('x'))
    exe = os.path.join(cm.ROOT, args.strata)
    os.makedirs(args.out, exist_ok=True)
    seeds = (args.seed, args.seed + 1)
    t0, machine0 = time.time(), cm.machine_line()
    sc = cm.SCENES['matte']
    strata = cm.strata_pair(exe, sc, args.out, 'matte', res, args.spp, args.max_depth, seeds,
                            f'--threads {args.threads} {args.strata_args}'.strip())
    cycles, version, pattern = cycles_pair(res, args.spp, args.max_depth, args.threads, seeds, args.out)
    row = cm.equal_error_row(sc, 'matte', res, args.spp, strata, cycles, tolerance=CYCLES_TOLERANCE)
    agree = abs(row['mean_rel_diff']) <= args.agree + 3 * row['mean_rel_se']
    print(f"strata ({cm.strata_rev()}) vs Cycles (Blender {version}, CPU, sampling pattern {pattern}), "
          f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC: {res[0]}x{res[1]}, {args.spp} spp "
          f"x seeds {seeds[0]} and {seeds[1]}, {args.threads} threads, box filter, strata --max-depth "
          f"{args.max_depth} = Cycles max_bounces {args.max_depth - 1}; CPU time (user + sys)\n"
          f"machine: {machine0} at the start, {os.getloadavg()[0]:.2f} at the end; {time.time() - t0:.0f} s\n"
          f"command: {' '.join(['tools/compare_cycles.py'] + sys.argv[1:])}\n"
          f"mean images: strata {row['mean_strata']:.5f}, Cycles {row['mean_other']:.5f}: "
          f"{100 * row['mean_rel_diff']:+.3f} % ± {300 * row['mean_rel_se']:.3f} (3 se); "
          f"{'agree' if agree else 'DIFFER'} within {100 * args.agree:g} % + 3 se\n")
    print(cm.equal_error_table([row], 'Cycles'))
    if args.csv:
        cm.write_csv(args.csv, [row], dict(other=f'cycles {version} {pattern}', threads=args.threads,
                                           strata=cm.strata_rev(), machine=machine0))
        print(f"\nwrote {args.csv}")
    if not agree:
        sys.exit("the mean images differ beyond the tolerance: the ratios above compare different images")


def throughput(args):
    """One thread, the matte ball: samples (camera rays: pixels x spp) per CPU second of each
    renderer, from the marginal cost of a sample (the 1-spp render's CPU time taken off)."""
    res = tuple(int(v) for v in args.res.split('x'))
    exe = os.path.join(cm.ROOT, args.strata)
    os.makedirs(args.out, exist_ok=True)
    seeds = (args.seed, args.seed + 1)
    sc, n = cm.SCENES['matte'], res[0] * res[1]
    t0, machine0 = time.time(), cm.machine_line()
    rate = lambda cpus, cpu1: n * (args.spp - 1) / (np.mean(cpus) - cpu1) / 1e6
    _, cpus, cpu1 = cm.strata_pair(exe, sc, args.out, 'matte_1t', res, args.spp, args.max_depth, seeds, '--threads 1')
    rates = {'strata': rate(cpus, cpu1)}
    # Each variant in turn: llvm_ad_rgb runs a path per SIMD lane (16 on AVX-512), scalar_rgb
    # one path at a time as strata does, so the pair separates vector width from the rest.
    for variant in args.variant.split(','):
        mi = cm.load_mitsuba(variant, 1)
        scene = cm.mitsuba_scene(mi, sc, res, args.spp, args.max_depth, [])
        _, cpus, cpu1 = cm.mitsuba_pair(mi, scene, args.spp, seeds)
        rates[f'Mitsuba {mi.__version__} {mi.variant()}'] = rate(cpus, cpu1)
    try:
        import importlib.util
        have_bpy = importlib.util.find_spec('bpy') is not None
    except ValueError:
        have_bpy = False
    if have_bpy:
        (_, cpus, cpu1), version, _ = cycles_pair(res, args.spp, args.max_depth, 1, seeds, args.out)
        rates[f'Cycles {version}'] = rate(cpus, cpu1)
    print(f"one thread, matte ball, {res[0]}x{res[1]}, {args.spp} spp, --max-depth {args.max_depth}: "
          f"Msamples per CPU second ({datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC)\n"
          f"machine: {machine0} at the start, {os.getloadavg()[0]:.2f} at the end; {time.time() - t0:.0f} s\n"
          f"command: {' '.join(['tools/compare_cycles.py'] + sys.argv[1:])}\n")
    print("| renderer | Msamples / CPU s | strata / it |\n|---|---|---|")
    for name, r in rates.items():
        print(f"| {name} | {r:.2f} | {rates['strata'] / r:.2f}x |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    sub = ap.add_subparsers(dest='cmd', required=True)
    m = sub.add_parser('measure', help='equal-error CPU time, strata / Cycles, matte ball')
    m.add_argument('--agree', type=float, default=0.001,
                   help='relative tolerance of the whole-image means, on top of 3 standard errors')
    t = sub.add_parser('throughput', help='one thread: samples per CPU second, strata / Mitsuba / Cycles')
    t.add_argument('--variant', default='llvm_ad_rgb,scalar_rgb',
                   help="Mitsuba variants, comma-separated, each measured in turn")
    for p, res in ((m, '320x240'), (t, '640x480')):
        p.add_argument('--res', default=res)
        p.add_argument('--spp', type=int, default=64)
        p.add_argument('--max-depth', type=int, default=8)
        p.add_argument('--seed', type=int, default=1)
        p.add_argument('--strata', default='target/release/strata')
        p.add_argument('--out', default='/tmp/strata_vs_cycles')
    m.add_argument('--threads', type=int, default=2)
    m.add_argument('--csv', default=None)
    m.add_argument('--strata-args', default='')
    w = sub.add_parser('_cycles', help='(internal) the Cycles child process')
    for flag in ('--res', '--jobs', '--out'):
        w.add_argument(flag, required=True)
    w.add_argument('--max-depth', type=int, required=True)
    w.add_argument('--threads', type=int, required=True)
    w.add_argument('--untimed', action='store_true')
    args = ap.parse_args()
    {'measure': measure, 'throughput': throughput, '_cycles': cycles_worker}[args.cmd](args)


if __name__ == '__main__':
    main()
