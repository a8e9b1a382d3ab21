use super::*;
use crate::render::geometry::Triangle;
use glam::DMat4;
use glam::Vec2;

fn tri(p: [Vec3; 3]) -> Triangle {
    Triangle { p, n: [Vec3::Z; 3], uv: [Vec2::ZERO; 3], prim: 0, has_uv: false, primvars: Default::default() }
}

#[test]
fn closest_hit_and_barycentrics() {
    let near = tri([Vec3::new(-1.0, -1.0, 1.0), Vec3::new(1.0, -1.0, 1.0), Vec3::new(-1.0, 1.0, 1.0)]);
    let far = tri([Vec3::new(-5.0, -5.0, 3.0), Vec3::new(5.0, -5.0, 3.0), Vec3::new(-5.0, 5.0, 3.0)]);
    let accel = Accel::new(vec![far, near], vec![]);
    let hit = accel.intersect(Vec3::new(-0.5, -0.5, 0.0), Vec3::Z, 0.0, f32::INFINITY).unwrap();
    assert_eq!(hit.index, 1);
    assert!((hit.t - 1.0).abs() < 1e-6);
    assert!((hit.b1 - 0.25).abs() < 1e-6 && (hit.b2 - 0.25).abs() < 1e-6);
    assert!(accel.occluded(Vec3::new(-0.5, -0.5, 0.0), Vec3::Z, 0.0, 2.0));
    assert!(!accel.occluded(Vec3::new(-0.5, -0.5, 0.0), Vec3::Z, 0.0, 0.5));
    assert!(accel.intersect(Vec3::new(-0.5, -0.5, 0.0), -Vec3::Z, 0.0, f32::INFINITY).is_none());
}

/// obvhs' traversal culled boxes left within 1e-4 of the ray origin (its `EPSILON`, in
/// whatever units the BVH was built in); strata's traversal uses the ray's own `tmin`, in a
/// power-of-two-scaled space. A floor hit from 1e-5 of the scene's size above, at scales 1e-9
/// to 1e5, directly and through an instance (object space at unit size, the top level at `s`).
#[test]
fn hits_close_to_the_origin_at_every_scale() {
    for s in [1e-9f32, 1e-6, 1e-3, 1.0, 1e5] {
        let floor = |k: f32| {
            [
                tri([Vec3::new(-k, -k, 0.0), Vec3::new(k, -k, 0.0), Vec3::new(k, k, 0.0)]),
                tri([Vec3::new(-k, -k, 0.0), Vec3::new(k, k, 0.0), Vec3::new(-k, k, 0.0)]),
            ]
        };
        let direct = Accel::new(floor(s).to_vec(), vec![]);
        let prototype = Blas::new(floor(1.0).to_vec(), vec![]);
        let desc = InstanceDesc { to_world: DMat4::from_scale(glam::DVec3::splat(s as f64)), prototype: 0, prims: 0 };
        let instanced = Accel::with_instances(Blas::new(vec![], vec![]), vec![prototype], &[desc], vec![0]);
        for (name, accel) in [("direct", &direct), ("instanced", &instanced)] {
            for h in [1e-5f32, 0.3] {
                let o = Vec3::new(0.1 * s, 0.2 * s, h * s);
                let hit = accel.intersect(o, -Vec3::Z, 0.0, f32::INFINITY);
                let t = hit.map(|h| h.t).unwrap_or(f32::NAN);
                assert!((t / (h * s) - 1.0).abs() < 1e-5, "{name}, scale {s:e}, height {h}: t = {t}");
                assert!(accel.occluded(o, -Vec3::Z, 0.0, 2.0 * h * s), "{name}, scale {s:e}, height {h}");
                assert!(!accel.occluded(o, -Vec3::Z, 0.0, 0.5 * h * s), "{name}, scale {s:e}, height {h}");
            }
        }
    }
}

#[test]
fn shared_edge_is_watertight() {
    // Two triangles sharing the diagonal of a square; rays exactly on the diagonal must hit.
    let a = tri([Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0)]);
    let b = tri([Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0), Vec3::new(0.0, 1.0, 0.0)]);
    let accel = Accel::new(vec![a, b], vec![]);
    for i in 1..100 {
        let x = i as f32 / 100.0;
        let o = Vec3::new(x, x, 1.0);
        assert!(accel.intersect(o, -Vec3::Z, 0.0, f32::INFINITY).is_some(), "leak at {x}");
    }
}

#[test]
fn coincident_copies_build_fast_and_the_first_closest_copy_is_hit() {
    // Copies of one triangle have identical boxes, on which PLOC merged one pair per pass:
    // 20 000 copies took minutes. Grouped, they are one BVH primitive.
    let t = tri([Vec3::new(-1.0, -1.0, 2.0), Vec3::new(1.0, -1.0, 2.0), Vec3::new(0.0, 1.0, 2.0)]);
    let nearer = tri([Vec3::new(-1.0, -1.0, 1.0), Vec3::new(1.0, -1.0, 1.0), Vec3::new(0.0, 1.0, 1.0)]);
    let mut triangles = vec![t; 20_000];
    triangles.push(nearer);
    triangles.extend(vec![nearer; 20_000]);
    let accel = Accel::new(triangles, vec![]);
    let hit = accel.intersect(Vec3::ZERO, Vec3::Z, 0.0, f32::INFINITY).expect("hit");
    assert_eq!(hit.index, 20_000, "the first of the coincident nearest triangles");
    assert!(accel.occluded(Vec3::ZERO, Vec3::Z, 0.0, 1.5));
    assert!(!accel.occluded(Vec3::ZERO, Vec3::Z, 0.0, 0.5));
}

#[test]
fn non_finite_triangles_are_never_hit_and_never_reach_the_builder() {
    let bad = tri([Vec3::new(f32::NAN, 0.0, 1.0), Vec3::new(f32::INFINITY, 0.0, 1.0), Vec3::Y]);
    let good = tri([Vec3::new(-1.0, -1.0, 1.0), Vec3::new(1.0, -1.0, 1.0), Vec3::new(0.0, 1.0, 1.0)]);
    let accel = Accel::new(vec![bad, good], vec![]);
    assert_eq!(accel.intersect(Vec3::ZERO, Vec3::Z, 0.0, f32::INFINITY).map(|h| h.index), Some(1));
    let only_bad = Accel::new(vec![bad], vec![]);
    assert!(only_bad.intersect(Vec3::ZERO, Vec3::Z, 0.0, f32::INFINITY).is_none());
    assert_eq!(only_bad.triangle_count(), 1);
}

#[test]
fn offset_origin_escapes_surface() {
    let t = tri([Vec3::new(-100.0, -100.0, 7.3), Vec3::new(100.0, -100.0, 7.3), Vec3::new(0.0, 100.0, 7.3)]);
    let accel = Accel::new(vec![t], vec![]);
    let hit = accel.intersect(Vec3::new(0.123, 0.456, 20.0), -Vec3::Z, 0.0, f32::INFINITY).unwrap();
    let g = accel.surface(Vec3::new(0.123, 0.456, 20.0), -Vec3::Z, &hit);
    assert!(g.p_error.max_element() > 0.0 && g.p_error.max_element() < 1e-4, "{}", g.p_error);
    let o = offset_ray_origin(g.p, g.p_error, Vec3::Z);
    assert!(o.z > 7.3);
    assert!(accel.intersect(o, Vec3::new(0.3, 0.0, 0.01).normalize(), 0.0, f32::INFINITY).is_none());
    let below = offset_ray_origin(g.p, g.p_error, -Vec3::Z);
    assert!(below.z < 7.3);
    assert!(accel.intersect(below - Vec3::Z, Vec3::new(0.3, 0.0, 0.1).normalize(), 0.0, f32::INFINITY).is_some());
}

/// A tilted square of `4 × 4` cells (32 coplanar triangles) of side `scale` around `centre`.
fn tilted_plane(scale: f32, centre: Vec3) -> (Vec<Triangle>, Vec3) {
    let (u, v) = (Vec3::new(0.8, 0.36, 0.48).normalize(), Vec3::new(-0.36, 0.93, 0.0));
    let v = (v - u * u.dot(v)).normalize();
    let at = |i: usize, j: usize| centre + (u * (i as f32 / 4.0 - 0.5) + v * (j as f32 / 4.0 - 0.5)) * scale;
    let mut out = Vec::new();
    for i in 0..4 {
        for j in 0..4 {
            out.push(tri([at(i, j), at(i + 1, j), at(i + 1, j + 1)]));
            out.push(tri([at(i, j), at(i + 1, j + 1), at(i, j + 1)]));
        }
    }
    (out, u.cross(v))
}

/// Rays that leave a surface point, from grazing (cos 1e-5 against the normal) to
/// straight out, on either side (`both_sides`; else outward only: into a sphere, a ray
/// meets its far side), never hit the surface they leave.
fn assert_no_self_hits(accel: &Accel, both_sides: bool, aim: impl Fn(usize) -> (Vec3, Vec3), what: &str) {
    let mut self_hits = 0;
    for i in 0..3000 {
        let (o, d) = aim(i);
        let Some(hit) = accel.intersect(o, d, 0.0, f32::INFINITY) else { continue };
        let g = accel.surface(o, d, &hit);
        let n = if i % 2 == 0 || !both_sides { g.ng } else { -g.ng };
        let t = n.any_orthonormal_vector();
        let t = (t * (i as f32 * 0.37).cos() + n.cross(t) * (i as f32 * 0.37).sin()).normalize();
        let cos = 10f32.powf(-5.0 * (i % 60) as f32 / 59.0);
        let out = (n * cos + t * (1.0 - cos * cos).sqrt()).normalize();
        let start = offset_ray_origin(g.p, g.p_error, n);
        if accel.intersect(start, out, 0.0, f32::INFINITY).is_some() || accel.occluded(start, out, 0.0, f32::INFINITY) {
            self_hits += 1;
        }
    }
    assert_eq!(self_hits, 0, "{what}: rays re-hit the surface they leave");
}

#[test]
fn grazing_rays_never_rehit_their_surface_at_any_scale() {
    for (scale, centre) in [
        (1e-3, Vec3::ZERO),
        (1.0, Vec3::new(0.3, -0.2, 0.1)),
        (1e5, Vec3::ZERO),
        (1e5, Vec3::new(3e6, -1e6, 2e6)),
        (1e-3, Vec3::new(1.0, 2.0, -3.0)),
    ] {
        let (plane, n) = tilted_plane(scale, centre);
        let sphere = Shape::new(
            crate::render::geometry::shapes::Part::Sphere {
                r: 1.0,
                cz: 0.0,
                zmin: f64::NEG_INFINITY,
                zmax: f64::INFINITY,
            },
            DMat4::from_scale_rotation_translation(
                glam::DVec3::new(1.0, 0.6, 0.8) * scale as f64 * 0.2,
                glam::DQuat::from_rotation_y(0.4),
                (centre + n * scale).as_dvec3(),
            ),
            0,
        )
        .unwrap();
        // Flat and convex: a ray leaving either never meets it again.
        let worlds = [Accel::new(plane.clone(), vec![]), Accel::new(vec![], vec![sphere.clone()])];
        let sphere_at = centre + n * scale;
        let aim = |i: usize| {
            // Half the rays at the plane from both sides, half at the sphere.
            let s = (i as f32 * 0.618_034).fract() - 0.5;
            let r = (i as f32 * 0.414_214).fract() - 0.5;
            let side = if i % 4 < 2 { 1.0 } else { -1.0 };
            if i.is_multiple_of(3) {
                let target = sphere_at + Vec3::new(s, r, s * r) * (0.2 * scale);
                let o = sphere_at + Vec3::new(r, 1.0, s).normalize() * (3.0 * scale);
                (o, (target - o).normalize())
            } else {
                let target = centre
                    + n.any_orthonormal_vector() * (s * 0.8 * scale)
                    + n.cross(n.any_orthonormal_vector()) * (r * 0.8 * scale);
                let o = target + (n * side + Vec3::new(r, s, 0.3) * 0.5) * scale;
                (o, (target - o).normalize())
            }
        };
        for (k, world) in worlds.iter().enumerate() {
            assert_no_self_hits(world, k == 0, aim, &format!("world {k}, scale {scale}, centre {centre}"));
        }
        // The same geometry as an instance: built around the origin at unit size, placed
        // by a transform that scales, turns and moves it.
        let (unit_plane, _) = tilted_plane(1.0, Vec3::ZERO);
        let unit_sphere = Shape::new(
            crate::render::geometry::shapes::Part::Sphere {
                r: 1.0,
                cz: 0.0,
                zmin: f64::NEG_INFINITY,
                zmax: f64::INFINITY,
            },
            DMat4::from_scale_rotation_translation(
                glam::DVec3::new(1.0, 0.6, 0.8) * 0.2,
                glam::DQuat::from_rotation_y(0.4),
                n.as_dvec3(),
            ),
            0,
        )
        .unwrap();
        let to_world = DMat4::from_translation(centre.as_dvec3()) * DMat4::from_scale(glam::DVec3::splat(scale as f64));
        let instanced = Accel::with_instances(
            Blas::new(Vec::new(), Vec::new()),
            vec![Blas::new(unit_plane, vec![]), Blas::new(vec![], vec![unit_sphere.clone()])],
            &[InstanceDesc { to_world, prototype: 0, prims: 0 }, InstanceDesc { to_world, prototype: 1, prims: 0 }],
            vec![0],
        );
        assert_eq!(instanced.blas_count(), 2);
        // Each instance alone (the other one's prototype is placed out of the way).
        for k in 0..2 {
            let away = DMat4::from_translation(glam::DVec3::splat(9e6));
            let descs: Vec<InstanceDesc> = (0..2)
                .map(|p| InstanceDesc { to_world: if p == k { to_world } else { away }, prototype: p, prims: 0 })
                .collect();
            let alone = Accel::with_instances(
                Blas::new(Vec::new(), Vec::new()),
                vec![Blas::new(tilted_plane(1.0, Vec3::ZERO).0, vec![]), Blas::new(vec![], vec![unit_sphere.clone()])],
                &descs,
                vec![0],
            );
            assert_no_self_hits(&alone, k == 0, aim, &format!("instance {k}, scale {scale}, centre {centre}"));
        }
    }
}

/// Brute force over every triangle with the same watertight test: the nearest `t` and
/// every triangle hit at exactly that `t` (a ray through a shared edge hits both).
fn brute_force(tris: &[[Vec3; 3]], o: Vec3, d: Vec3, tmax: f32) -> Option<(f32, Vec<u32>)> {
    let test = |p: &[Vec3; 3]| match dominant_axis(d) {
        0 => RayPre::<0>::new(o, d).intersect(p, 0.0, tmax),
        1 => RayPre::<1>::new(o, d).intersect(p, 0.0, tmax),
        _ => RayPre::<2>::new(o, d).intersect(p, 0.0, tmax),
    };
    let hits: Vec<(f32, u32)> = tris.iter().enumerate().filter_map(|(i, p)| test(p).map(|h| (h.0, i as u32))).collect();
    let t = hits.iter().map(|h| h.0).reduce(f32::min)?;
    Some((t, hits.iter().filter(|h| h.0 == t).map(|h| h.1).collect()))
}

/// A random mesh: a jittered grid of `n` x `n` quads folded into hills (shared edges and
/// vertices, as real meshes have), plus `loose` free triangles anywhere.
fn random_mesh(n: usize, heights: &[f32], loose: &[[f32; 9]]) -> Vec<[Vec3; 3]> {
    let vertex = |i: usize, j: usize| {
        let h = heights[(i * (n + 1) + j) % heights.len()];
        Vec3::new(i as f32 / n as f32 - 0.5, h, j as f32 / n as f32 - 0.5)
    };
    let mut tris = Vec::new();
    for i in 0..n {
        for j in 0..n {
            tris.push([vertex(i, j), vertex(i + 1, j), vertex(i, j + 1)]);
            tris.push([vertex(i + 1, j), vertex(i + 1, j + 1), vertex(i, j + 1)]);
        }
    }
    for c in loose {
        tris.push([Vec3::new(c[0], c[1], c[2]), Vec3::new(c[3], c[4], c[5]), Vec3::new(c[6], c[7], c[8])]);
    }
    tris
}

/// Checks `accel`'s closest hit against brute force over `tris`, and occlusion against
/// the closest hit at each ray's length.
fn agrees_with_brute_force(
    tris: &[[Vec3; 3]],
    rays: Vec<([f32; 3], [f32; 3], f32)>,
) -> Result<(), proptest::test_runner::TestCaseError> {
    let accel = Accel::new(tris.iter().map(|&p| tri(p)).collect::<Vec<_>>(), Vec::new());
    for (o, d, length) in rays {
        let (o, d) = (Vec3::from(o), Vec3::from(d).normalize_or_zero());
        if d == Vec3::ZERO {
            continue;
        }
        let expected = brute_force(tris, o, d, f32::INFINITY);
        let got = accel.intersect(o, d, 0.0, f32::INFINITY);
        match (&expected, got) {
            (None, None) => {}
            (Some((t, indices)), Some(hit)) => {
                proptest::prop_assert_eq!(hit.t, *t);
                proptest::prop_assert!(indices.contains(&hit.index), "hit {} not among {:?}", hit.index, indices);
            }
            _ => proptest::prop_assert!(false, "BVH {:?}, brute force {:?}, ray {} {}", got, expected, o, d),
        }
        let blocked = expected.as_ref().is_some_and(|(t, _)| *t < length);
        proptest::prop_assert_eq!(accel.occluded(o, d, 0.0, length), blocked, "ray {} {} length {}", o, d, length);
    }
    Ok(())
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig { cases: 64, ..Default::default() })]

    /// The wide BVH (on whichever node test this CPU runs) finds the nearest hit brute
    /// force finds, and occlusion agrees with the closest hit at every ray length.
    #[test]
    fn wide_bvh_finds_the_brute_force_nearest_hit(
        n in 1usize..24,
        heights in proptest::collection::vec(-0.3f32..0.3, 1..64),
        loose in proptest::collection::vec(proptest::array::uniform9(-1.0f32..1.0), 0..40),
        rays in proptest::collection::vec((proptest::array::uniform3(-2.0f32..2.0), proptest::array::uniform3(-1.0f32..1.0), 0.05f32..4.0), 64),
    ) {
        agrees_with_brute_force(&random_mesh(n, &heights, &loose), rays)?;
    }

    /// So does a BLAS small enough to be flat (no BVH), and one just past the threshold.
    #[test]
    fn flat_blas_finds_the_brute_force_nearest_hit(
        loose in proptest::collection::vec(proptest::array::uniform9(-1.0f32..1.0), 0..=FLAT_PRIMITIVES + 2),
        rays in proptest::collection::vec((proptest::array::uniform3(-2.0f32..2.0), proptest::array::uniform3(-1.0f32..1.0), 0.05f32..4.0), 64),
    ) {
        agrees_with_brute_force(&random_mesh(0, &[0.0], &loose), rays)?;
    }
}

/// Every BVH leaf of at most one block's slots lies in one block of the leaf-order
/// triangles (the padding before it makes the AVX2 test one pass per leaf), the padding slots
/// lie in no leaf, and every triangle lies in exactly one leaf, coincident copies (one group
/// of more members than a block holds) included.
#[test]
fn small_leaves_lie_in_one_block_and_padding_in_none() {
    let mut tris = random_mesh(40, &[0.0, 0.1, -0.2, 0.05, 0.3, -0.1, 0.02], &[]);
    tris.extend(std::iter::repeat_n(tris[7], 20));
    let blas = Blas::new(tris.iter().map(|&p| tri(p)).collect::<Vec<_>>(), vec![]);
    let space = blas.bvh.as_ref().expect("a BVH");
    let mut leaves_of_slot = vec![0u32; blas.group_members.len()];
    let mut large = 0;
    for (first, count) in space.bvh.leaves() {
        let (a, b) = (first as usize, (first + count) as usize);
        leaves_of_slot[a..b].iter_mut().for_each(|n| *n += 1);
        if b - a <= leaves::LANES {
            assert_eq!(a / leaves::LANES, (b - 1) / leaves::LANES, "leaf {a}..{b} straddles two blocks");
        } else {
            large += 1;
        }
    }
    assert!(large > 0, "the coincident copies make a leaf larger than a block");
    let mut seen = vec![false; tris.len()];
    for (slot, &member) in blas.group_members.iter().enumerate() {
        if member == leaves::NO_PRIMITIVE {
            assert_eq!(leaves_of_slot[slot], 0, "padding slot {slot} in a leaf");
        } else {
            assert_eq!(leaves_of_slot[slot], 1, "slot {slot}");
            assert!(!std::mem::replace(&mut seen[member as usize], true), "triangle {member} twice");
        }
    }
    assert!(seen.iter().all(|&s| s), "every triangle in a leaf");
    assert!(blas.group_members.contains(&leaves::NO_PRIMITIVE), "some leaf needed padding");
}

/// A leaf's closest distance is unscaled by `1 / k` instead of divided by `k`: bit for bit
/// the division's result, for every normal power of two `k` a BVH space can give and
/// distances of every magnitude (so a render through a scaled BVH is the same either way).
#[test]
fn unscaling_by_the_reciprocal_rounds_as_the_division() {
    let mut bits = 0x1234_5678u32;
    for m in -126..=127 {
        let k = f32::from_bits(((m + 127) as u32) << 23);
        assert!(k.is_normal());
        for _ in 0..500 {
            bits ^= bits << 13;
            bits ^= bits >> 17;
            bits ^= bits << 5;
            // Any finite non-negative distance, subnormals included.
            let t = f32::from_bits(bits % 0x7f80_0000);
            assert_eq!(unscale(t, 1.0 / k, f32::INFINITY).to_bits(), (t / k).to_bits(), "t {t:e}, k 2^{m}");
        }
    }
}

/// `traceable` refuses a ray with any non-finite component or a zero direction, and takes
/// every other (negative zeros, the largest finite values, subnormals).
#[test]
fn only_finite_rays_with_a_direction_are_traceable() {
    let finite = [0.0, -0.0, 1.0, -3.5, f32::MAX, f32::MIN, f32::MIN_POSITIVE / 4.0];
    for (i, &x) in finite.iter().enumerate() {
        let o = Vec3::new(x, finite[(i + 1) % finite.len()], -x);
        assert!(traceable(o, Vec3::new(0.0, x, 1.0)), "{o}");
    }
    for bad in [f32::INFINITY, f32::NEG_INFINITY, f32::NAN] {
        for axis in 0..6 {
            let mut v = [1.0f32, -2.0, 0.0, 0.5, 0.0, -1.0];
            v[axis] = bad;
            let (o, d) = (Vec3::new(v[0], v[1], v[2]), Vec3::new(v[3], v[4], v[5]));
            assert!(!traceable(o, d), "{o} {d}");
        }
    }
    assert!(!traceable(Vec3::ONE, Vec3::ZERO) && !traceable(Vec3::ONE, -Vec3::ZERO));
}
