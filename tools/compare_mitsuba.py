"""The same scene as scenes/compare/matte_ball.usda (a diffuse ball on a diffuse floor under a
constant white dome, 640x480, 64 spp, box filter) rendered by Mitsuba 3's LLVM variant, three
times; the first run includes its kernel compilation. Compare with
    strata render scenes/compare/matte_ball.usda -o strata.exr --spp 64 --max-depth 8
Needs `pip install mitsuba numpy` and a libLLVM >= 17 (point DRJIT_LIBLLVM_PATH at it).
Not part of the test suite.
"""
import time, sys, mitsuba as mi
mi.set_variant(sys.argv[1] if len(sys.argv) > 1 else 'llvm_ad_rgb')
T = mi.ScalarTransform4f
spp = 64
scene = mi.load_dict({
    'type': 'scene',
    'integrator': {'type': 'path', 'max_depth': 9, 'rr_depth': 5},
    'sensor': {'type': 'perspective', 'fov': 54.43, 'fov_axis': 'x',
               'to_world': T().look_at(origin=[0, 1.4, 6.5], target=[0, 0.8, 0], up=[0, 1, 0]),
               'film': {'type': 'hdrfilm', 'width': 640, 'height': 480, 'rfilter': {'type': 'box'}},
               'sampler': {'type': 'independent', 'sample_count': spp}},
    'env': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': 1.0}},
    'floor': {'type': 'rectangle', 'to_world': T().rotate([1, 0, 0], -90).scale(6),
              'bsdf': {'type': 'diffuse', 'reflectance': {'type': 'rgb', 'value': 0.5}}},
    'ball': {'type': 'sphere', 'center': [0, 0.8, 0], 'radius': 0.8,
             'bsdf': {'type': 'diffuse', 'reflectance': {'type': 'rgb', 'value': 0.8}}},
})
for k in range(3):
    t = time.time()
    img = mi.render(scene, spp=spp, seed=k)
    mi.Float(img.array).numpy()  # force evaluation
    print(f"run {k}: {time.time() - t:.2f} s")
mi.util.write_bitmap("mitsuba.png", img)
