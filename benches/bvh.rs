//! Ray-traversal benchmark: strata's BVH ([`strata::render::geometry::accel::Accel`]) on bumpy spheres
//! of 1 to 10⁶ triangles, primary, diffuse-bounce and shadow rays, one thread; with
//! `--features embree`, Intel Embree 3 (Debian's `libembree-dev`) on the very same triangles
//! and rays, and the ratio of the two.
//!
//! ```text
//! cargo bench --bench bvh --features embree            # strata and Embree
//! cargo bench --bench bvh                               # strata only
//! cargo bench --bench bvh --features embree -- 1000    # sizes of your choice
//! ```
//!
//! Speeds are rays per CPU-second of the measuring thread (the machine may be shared: CPU
//! time is what a loaded machine does not inflate), best of three alternating rounds, so both
//! libraries see the same load. Build time is wall-clock of `Accel::new` and of Embree's
//! `rtcCommitScene`; bytes per triangle are strata's [`Accel::bytes`] (triangles, their
//! attributes and the BVH).

use glam::{Vec2, Vec3};
use std::hint::black_box;
use std::time::Instant;
use strata::render::geometry::Triangle;
use strata::render::geometry::accel::{Accel, offset_ray_origin};
use strata::render::geometry::primvars::PrimvarRef;

/// Rays per kind per round.
const RAYS: usize = 1 << 17;

/// A small deterministic generator (SplitMix64), so every run traces the same rays.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// A unit sphere with bumps of 5 % (so rays meet triangles at every angle and the BVH is not
/// one of a regular grid), tessellated to about `n` triangles; one triangle for `n` = 1.
fn bumpy_sphere(n: usize) -> Vec<[Vec3; 3]> {
    if n < 8 {
        return vec![[Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, -1.0, 0.0), Vec3::new(0.0, 1.0, 0.0)]];
    }
    let rows = ((n as f64 / 4.0).sqrt().round() as usize).max(2);
    let cols = 2 * rows;
    let point = |i: usize, j: usize| {
        let theta = std::f32::consts::PI * i as f32 / rows as f32;
        let phi = std::f32::consts::TAU * (j % cols) as f32 / cols as f32;
        let r = 1.0 + 0.05 * (7.0 * theta).sin() * (5.0 * phi).cos();
        r * Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos())
    };
    let mut tris = Vec::with_capacity(2 * rows * cols);
    for i in 0..rows {
        for j in 0..cols {
            let (a, b, c, d) = (point(i, j), point(i, j + 1), point(i + 1, j), point(i + 1, j + 1));
            tris.push([a, c, b]);
            tris.push([b, c, d]);
        }
    }
    tris
}

/// A ray `o + t d`, `t` in `(0, tmax)`.
#[derive(Clone, Copy)]
struct TestRay {
    o: Vec3,
    d: Vec3,
    tmax: f32,
}

/// The three ray sets: camera rays through a 4×4 window at z = 3 aimed at the mesh; diffuse
/// rays (cosine-distributed) and shadow rays (to a point light) from where camera rays hit.
fn ray_sets(accel: &Accel) -> [(&'static str, Vec<TestRay>); 3] {
    let mut rng = Rng(7);
    let eye = Vec3::new(0.0, 0.0, 3.0);
    let light = Vec3::new(4.0, 5.0, 6.0);
    let mut primary = Vec::with_capacity(RAYS);
    let mut diffuse = Vec::with_capacity(RAYS);
    let mut shadow = Vec::with_capacity(RAYS);
    while primary.len() < RAYS {
        let target = Vec3::new(2.4 * rng.next() - 1.2, 2.4 * rng.next() - 1.2, 0.0);
        let d = (target - eye).normalize();
        primary.push(TestRay { o: eye, d, tmax: f32::INFINITY });
        let Some(hit) = accel.intersect(eye, d, 0.0, f32::INFINITY) else { continue };
        let g = accel.surface(eye, d, &hit);
        let n = if g.ng.dot(d) > 0.0 { -g.ng } else { g.ng };
        let o = offset_ray_origin(g.p, g.p_error, n);
        let (u1, u2) = (rng.next(), rng.next());
        let (r, phi) = (u1.sqrt(), std::f32::consts::TAU * u2);
        let (t, b) = n.any_orthonormal_pair();
        let dir = (t * r * phi.cos() + b * r * phi.sin() + n * (1.0 - u1).max(0.0).sqrt()).normalize();
        diffuse.push(TestRay { o, d: dir, tmax: f32::INFINITY });
        let to_light = light - o;
        shadow.push(TestRay { o, d: to_light.normalize(), tmax: to_light.length() });
    }
    // Secondary rays exist only where camera rays hit: as many as there are such hits, repeated
    // to the same count (a 1-triangle scene has few).
    let fill = |v: &mut Vec<TestRay>| {
        if !v.is_empty() {
            let mut i = 0;
            while v.len() < RAYS {
                v.push(v[i]);
                i += 1;
            }
        }
    };
    fill(&mut diffuse);
    fill(&mut shadow);
    [("primary", primary), ("diffuse", diffuse), ("shadow", shadow)]
}

/// CPU time of the calling thread, in seconds.
fn thread_cpu_seconds() -> f64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid timespec to write to.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// Rays per CPU-second of `trace` over `rays`, and a checksum (hits) so nothing is optimised away.
fn measure(rays: &[TestRay], mut trace: impl FnMut(&TestRay) -> bool) -> (f64, usize) {
    let start = thread_cpu_seconds();
    let hits = rays.iter().filter(|r| trace(black_box(r))).count();
    let secs = (thread_cpu_seconds() - start).max(1e-9);
    (rays.len() as f64 / secs, hits)
}

#[cfg(feature = "embree")]
mod embree {
    //! The handful of Embree 3 entry points the benchmark needs (`/usr/include/embree3`).
    use super::TestRay;
    use std::ffi::c_void;

    type Device = *mut c_void;
    type Scene = *mut c_void;
    type Geometry = *mut c_void;

    const GEOMETRY_TYPE_TRIANGLE: u32 = 0;
    const BUFFER_TYPE_INDEX: u32 = 0;
    const BUFFER_TYPE_VERTEX: u32 = 1;
    const FORMAT_UINT3: u32 = 0x5003;
    const FORMAT_FLOAT3: u32 = 0x9003;
    const INVALID_ID: u32 = u32::MAX;

    #[repr(C, align(16))]
    #[derive(Clone, Copy)]
    struct RtcRay {
        org: [f32; 3],
        tnear: f32,
        dir: [f32; 3],
        time: f32,
        tfar: f32,
        mask: u32,
        id: u32,
        flags: u32,
    }

    #[repr(C, align(16))]
    #[derive(Clone, Copy)]
    struct RtcHit {
        ng: [f32; 3],
        u: f32,
        v: f32,
        prim_id: u32,
        geom_id: u32,
        inst_id: [u32; 1],
    }

    #[repr(C)]
    struct RtcRayHit {
        ray: RtcRay,
        hit: RtcHit,
    }

    /// `RTCIntersectContext` with `RTC_MAX_INSTANCE_LEVEL_COUNT` 1 and `RTC_MIN_WIDTH` 0.
    #[repr(C)]
    struct Context {
        flags: u32,
        filter: *const c_void,
        inst_id: [u32; 1],
    }

    #[link(name = "embree3")]
    unsafe extern "C" {
        fn rtcNewDevice(config: *const i8) -> Device;
        fn rtcReleaseDevice(device: Device);
        fn rtcNewScene(device: Device) -> Scene;
        fn rtcReleaseScene(scene: Scene);
        fn rtcNewGeometry(device: Device, kind: u32) -> Geometry;
        fn rtcSetSharedGeometryBuffer(
            geometry: Geometry,
            kind: u32,
            slot: u32,
            format: u32,
            ptr: *const c_void,
            byte_offset: usize,
            byte_stride: usize,
            count: usize,
        );
        fn rtcCommitGeometry(geometry: Geometry);
        fn rtcAttachGeometry(scene: Scene, geometry: Geometry) -> u32;
        fn rtcReleaseGeometry(geometry: Geometry);
        fn rtcCommitScene(scene: Scene);
        fn rtcIntersect1(scene: Scene, context: *mut Context, rayhit: *mut RtcRayHit);
        fn rtcOccluded1(scene: Scene, context: *mut Context, ray: *mut RtcRay);
    }

    /// An Embree scene over one triangle mesh; owns the buffers Embree shares.
    pub struct Embree {
        device: Device,
        scene: Scene,
        _vertices: Vec<f32>,
        _indices: Vec<u32>,
    }

    impl Embree {
        /// Builds Embree's BVH over `triangles` (default build quality, as a renderer would).
        pub fn new(triangles: &[[glam::Vec3; 3]]) -> Embree {
            // One padding float at the end: Embree reads vertices with 16-byte loads.
            let mut vertices: Vec<f32> = triangles.iter().flat_map(|t| t.iter().flat_map(|v| v.to_array())).collect();
            vertices.push(0.0);
            let indices: Vec<u32> = (0..3 * triangles.len() as u32).collect();
            // SAFETY: the calls follow Embree's API; the shared buffers live as long as the scene.
            unsafe {
                let device = rtcNewDevice(std::ptr::null());
                assert!(!device.is_null(), "rtcNewDevice failed");
                let scene = rtcNewScene(device);
                let geometry = rtcNewGeometry(device, GEOMETRY_TYPE_TRIANGLE);
                let vertex_count = 3 * triangles.len();
                rtcSetSharedGeometryBuffer(
                    geometry,
                    BUFFER_TYPE_VERTEX,
                    0,
                    FORMAT_FLOAT3,
                    vertices.as_ptr().cast(),
                    0,
                    12,
                    vertex_count,
                );
                rtcSetSharedGeometryBuffer(
                    geometry,
                    BUFFER_TYPE_INDEX,
                    0,
                    FORMAT_UINT3,
                    indices.as_ptr().cast(),
                    0,
                    12,
                    triangles.len(),
                );
                rtcCommitGeometry(geometry);
                rtcAttachGeometry(scene, geometry);
                rtcReleaseGeometry(geometry);
                rtcCommitScene(scene);
                Embree { device, scene, _vertices: vertices, _indices: indices }
            }
        }

        fn ray(r: &TestRay) -> RtcRay {
            RtcRay {
                org: r.o.to_array(),
                tnear: 0.0,
                dir: r.d.to_array(),
                time: 0.0,
                tfar: r.tmax,
                mask: u32::MAX,
                id: 0,
                flags: 0,
            }
        }

        fn context() -> Context {
            Context { flags: 0, filter: std::ptr::null(), inst_id: [INVALID_ID] }
        }

        /// The closest hit's distance and triangle.
        pub fn intersect(&self, r: &TestRay) -> Option<(f32, u32)> {
            let mut rh = RtcRayHit {
                ray: Embree::ray(r),
                hit: RtcHit {
                    ng: [0.0; 3],
                    u: 0.0,
                    v: 0.0,
                    prim_id: INVALID_ID,
                    geom_id: INVALID_ID,
                    inst_id: [INVALID_ID],
                },
            };
            let mut context = Embree::context();
            // SAFETY: a committed scene, a valid context and ray.
            unsafe { rtcIntersect1(self.scene, &mut context, &mut rh) };
            (rh.hit.geom_id != INVALID_ID).then_some((rh.ray.tfar, rh.hit.prim_id))
        }

        /// Whether anything lies on the ray.
        pub fn occluded(&self, r: &TestRay) -> bool {
            let mut ray = Embree::ray(r);
            let mut context = Embree::context();
            // SAFETY: as above; Embree sets `tfar` to −∞ on a hit.
            unsafe { rtcOccluded1(self.scene, &mut context, &mut ray) };
            ray.tfar < 0.0
        }
    }

    impl Drop for Embree {
        fn drop(&mut self) {
            // SAFETY: created in `new`, released once.
            unsafe {
                rtcReleaseScene(self.scene);
                rtcReleaseDevice(self.device);
            }
        }
    }
}

fn main() {
    let sizes: Vec<usize> = {
        let given: Vec<usize> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
        if given.is_empty() { vec![1, 100, 1_000, 10_000, 100_000, 1_000_000] } else { given }
    };
    println!("rays per CPU-second of one thread (M = 10⁶), best of 3; {RAYS} rays per set");
    for &n in &sizes {
        let positions = bumpy_sphere(n);
        let triangles: Vec<Triangle> = positions
            .iter()
            .map(|&p| Triangle {
                p,
                n: [(p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero(); 3],
                uv: [Vec2::ZERO, Vec2::X, Vec2::Y],
                prim: 0,
                has_uv: false,
                primvars: PrimvarRef::NONE,
            })
            .collect();
        let count = triangles.len();
        let start = Instant::now();
        let accel = Accel::new(triangles, Vec::new());
        let build = start.elapsed().as_secs_f64();
        let bytes = accel.bytes().0 as f64 / count as f64;
        println!("\n{count} triangles: strata build {build:.3} s, {bytes:.0} bytes/triangle");
        #[cfg(feature = "embree")]
        let embree = {
            let start = Instant::now();
            let e = embree::Embree::new(&positions);
            println!("  Embree build {:.3} s", start.elapsed().as_secs_f64());
            e
        };
        for (kind, rays) in ray_sets(&accel) {
            if rays.is_empty() {
                continue;
            }
            let shadow = kind == "shadow";
            let mut best_strata: f64 = 0.0;
            #[cfg(feature = "embree")]
            let mut best_embree: f64 = 0.0;
            for _ in 0..3 {
                let (speed, strata_hits) = measure(&rays, |r| {
                    if shadow {
                        accel.occluded(r.o, r.d, 0.0, r.tmax)
                    } else {
                        accel.intersect(r.o, r.d, 0.0, r.tmax).is_some()
                    }
                });
                best_strata = best_strata.max(speed);
                #[cfg(feature = "embree")]
                {
                    let (speed, embree_hits) =
                        measure(&rays, |r| if shadow { embree.occluded(r) } else { embree.intersect(r).is_some() });
                    best_embree = best_embree.max(speed);
                    // Both must agree up to rays that graze an edge at f32 resolution.
                    let tolerance = rays.len() / 1000 + 1;
                    assert!(
                        strata_hits.abs_diff(embree_hits) <= tolerance,
                        "{kind}: strata hits {strata_hits}, Embree {embree_hits}"
                    );
                }
                #[cfg(not(feature = "embree"))]
                black_box(strata_hits);
            }
            #[cfg(feature = "embree")]
            println!(
                "  {kind:8} strata {:7.2} M/s   Embree {:7.2} M/s   ratio {:.2}",
                best_strata * 1e-6,
                best_embree * 1e-6,
                best_strata / best_embree
            );
            #[cfg(not(feature = "embree"))]
            println!("  {kind:8} strata {:7.2} M/s", best_strata * 1e-6);
        }
    }
}
