//! A hit's surface frame: the winding normal, the shading normal kept on its side, and ∂P/∂u,
//! ∂P/∂v from texture coordinates or the triangle's edges (a frame around the normal where they
//! are degenerate).

use crate::render::material::frame::Frame;
use glam::{Vec2, Vec3};

/// The unit normal of `p` by winding, computed in f64 (exact products of the f32 inputs)
/// so that it does not underflow for tiny triangles as an f32 cross product does (edges below
/// ~1e-10 units); zero when the vertices are collinear.
#[inline]
pub(super) fn winding_normal(p: [Vec3; 3]) -> Vec3 {
    let [a, b, c] = p.map(|v| v.as_dvec3());
    (b - a).cross(c - a).normalize_or_zero().as_vec3()
}

/// `(dpdu, dpdv)`, or a frame around `n` when they do not span a plane (at a pole ∂P/∂u
/// vanishes).
pub(super) fn frame_or(dpdu: Vec3, dpdv: Vec3, n: Vec3) -> (Vec3, Vec3) {
    if dpdu.cross(dpdv).length_squared() > 0.0 && dpdu.is_finite() && dpdv.is_finite() {
        (dpdu, dpdv)
    } else {
        let f = Frame::from_normal(n);
        (f.t, f.b)
    }
}

/// The interpolated shading normal, normalised and kept on the geometric normal's side
/// (shading normals are authored on either side); `ng` when it vanishes.
pub(super) fn shading_normal(n: Vec3, ng: Vec3) -> Vec3 {
    let ns = n.normalize_or_zero();
    if ns == Vec3::ZERO || !ns.is_finite() {
        ng
    } else if ns.dot(ng) < 0.0 {
        -ns
    } else {
        ns
    }
}

/// dP/du and dP/dv from the triangle's texture coordinates, or a frame around `n` when
/// they are degenerate.
pub(crate) fn tangents(p: [Vec3; 3], uv: [Vec2; 3], n: Vec3) -> (Vec3, Vec3) {
    let d1 = uv[1] - uv[0];
    let d2 = uv[2] - uv[0];
    let det = d1.x * d2.y - d1.y * d2.x;
    let e1 = p[1] - p[0];
    let e2 = p[2] - p[0];
    if det.abs() > 1e-12 {
        let inv = 1.0 / det;
        let dpdu = (e1 * d2.y - e2 * d1.y) * inv;
        let dpdv = (e2 * d1.x - e1 * d2.x) * inv;
        if dpdu.is_finite() && dpdv.is_finite() && dpdu.cross(dpdv).length_squared() > 0.0 {
            return (dpdu, dpdv);
        }
    }
    let f = Frame::from_normal(n);
    (f.t, f.b)
}

/// [`tangents`] for the parametric coordinates `(0,0), (1,0), (0,1)`: the edges from corner 0,
/// or a frame around `n` when they do not span a plane.
#[inline]
pub(super) fn edge_tangents(p: [Vec3; 3], n: Vec3) -> (Vec3, Vec3) {
    let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
    if e1.is_finite() && e2.is_finite() && e1.cross(e2).length_squared() > 0.0 {
        (e1, e2)
    } else {
        let f = Frame::from_normal(n);
        (f.t, f.b)
    }
}
