//! Orbit, pan and dolly around a pivot, as DCC viewports do: dragging turns the camera about
//! the stage's up axis and its own right axis, keeping the pivot in the middle of the image.

use crate::render::camera::Camera;
use glam::{Quat, Vec3};
use serde::Deserialize;

/// A camera move from the page, in fractions of the image (a drag across the whole width is 1).
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Move {
    /// Turn about the pivot: a full-width drag is half a turn.
    Orbit { dx: f32, dy: f32 },
    /// Slide the camera and the pivot in the image plane.
    Pan { dx: f32, dy: f32 },
    /// Move towards the pivot by `factor` of the distance (below 1: closer).
    Dolly { factor: f32 },
}

/// The pivot and the stage's up axis.
pub struct Orbit {
    up: Vec3,
    /// Distance from the camera to the pivot, along its view direction.
    distance: f32,
}

impl Orbit {
    /// The orbit of `camera` about the point of its view axis nearest the centre of `bounds`.
    pub fn new(camera: &Camera, bounds: (Vec3, Vec3), up_axis: &str) -> Orbit {
        let centre = (bounds.0 + bounds.1) * 0.5;
        let along = (centre - camera.origin()).dot(camera.forward());
        let size = (bounds.1 - bounds.0).length().max(1e-3);
        let up = if up_axis == "Z" { Vec3::Z } else { Vec3::Y };
        Orbit { up, distance: if along > 1e-3 * size { along } else { size } }
    }

    /// `camera` after `m`.
    pub fn apply(&mut self, camera: &Camera, m: Move) -> Camera {
        let (origin, forward, up) = (camera.origin(), camera.forward(), camera.up());
        let pivot = origin + forward * self.distance;
        match m {
            Move::Orbit { dx, dy } => {
                let (dx, dy) = (finite(dx), finite(dy));
                let yaw = Quat::from_axis_angle(self.up, -dx * std::f32::consts::PI);
                let pitch = Quat::from_axis_angle(camera.right(), -dy * std::f32::consts::PI);
                let turn = yaw * pitch;
                let (forward, up) = (turn * forward, turn * up);
                // Never roll over the pole: keep the image's up on the stage's up side.
                if up.dot(self.up) <= 0.05 {
                    return camera.posed(
                        pivot - (yaw * camera.forward()) * self.distance,
                        yaw * camera.forward(),
                        self.up,
                    );
                }
                camera.posed(pivot - forward * self.distance, forward, self.up)
            }
            Move::Pan { dx, dy } => {
                let width = self.distance * camera.pixel_angle(1);
                let shift = (-camera.right() * finite(dx) + up * finite(dy)) * width;
                camera.posed(origin + shift, forward, up)
            }
            Move::Dolly { factor } => {
                let factor = if factor.is_finite() { factor.clamp(0.05, 20.0) } else { 1.0 };
                self.distance *= factor;
                camera.posed(pivot - forward * self.distance, forward, up)
            }
        }
    }
}

impl Orbit {
    /// `camera` turned nowhere but moved along its view axis so that a sphere about `centre`
    /// of `radius` fills the image (`aspect`: width / height); the pivot becomes `centre`.
    pub fn frame(&mut self, camera: &Camera, centre: Vec3, radius: f32, aspect: f32) -> Camera {
        let tan_half_x = camera.pixel_angle(1) / 2.0;
        let half = tan_half_x.min(tan_half_x / aspect.max(1e-6)).atan();
        self.distance = (radius / half.sin().max(1e-6)).max(1e-4);
        camera.posed(centre - camera.forward() * self.distance, camera.forward(), camera.up())
    }
}

fn finite(x: f32) -> f32 {
    if x.is_finite() { x.clamp(-4.0, 4.0) } else { 0.0 }
}
