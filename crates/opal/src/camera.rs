//! Perspective pinhole camera with Mitsuba 3's conventions (written out in
//! `docs/conventions.md`):
//! * `to_world` maps camera space to world; the camera looks along local +z, local +x is the
//!   image's *left*, local +y its up.
//! * Continuous film coordinates (px, py) ∈ [0, W] × [0, H], row 0 at the top; pixel (i, j)
//!   covers [i, i+1) × [j, j+1), its centre is (i + ½, j + ½).
//! * `d_local = (−(2px/W − 1)·tan(fx/2), −(2py/H − 1)·tan(fy/2), 1)` with
//!   `tan(fy/2) = tan(fx/2)·H/W`; `d_world = normalize(M₃ₓ₃ · d_local)`; origin = M's translation.
//!
//! Tests: `tests/mitsuba_cbox.rs` (`camera_rays_hit_mitsuba_aov_positions`) compares the rays with those of Mitsuba's pixel-centre AOV
//! (hit positions of 8 views) of the reference Cornell box.

use crate::geometry::Ray;
use crate::math::{Mat4, Vec2, Vec3};
use crate::scene::desc::SensorDesc;

/// A perspective pinhole camera.
#[derive(Clone, Debug)]
pub struct Camera {
    /// Identifier from the scene file.
    pub id: String,
    /// Camera-to-world matrix.
    pub to_world: Mat4,
    /// Film width in pixels.
    pub width: usize,
    /// Film height in pixels.
    pub height: usize,
    /// tan of half the horizontal field of view.
    pub tan_half_x: f32,
    /// tan of half the vertical field of view.
    pub tan_half_y: f32,
    /// Near clip distance (along the optical axis).
    pub near_clip: f32,
    /// Far clip distance (along the optical axis).
    pub far_clip: f32,
    /// Samples per pixel requested by the scene, if any.
    pub spp: Option<u32>,
    origin: Vec3,
    world_to_camera: Mat4,
}

impl Camera {
    /// Camera from its description.
    pub fn new(d: &SensorDesc) -> Self {
        let tan_half_x = (d.fov_x_deg.to_radians() * 0.5).tan();
        let tan_half_y = tan_half_x * d.height as f32 / d.width as f32;
        Camera {
            id: d.id.clone(),
            to_world: d.to_world,
            width: d.width,
            height: d.height,
            tan_half_x,
            tan_half_y,
            near_clip: d.near_clip,
            far_clip: d.far_clip,
            spp: d.spp,
            origin: d.to_world.w_axis.truncate(),
            world_to_camera: d.to_world.inverse(),
        }
    }

    /// Camera position in world space.
    pub fn origin(&self) -> Vec3 {
        self.origin
    }

    /// Direction of the camera ray through continuous film position `p` (pixels), in camera
    /// space (not normalised, z = 1).
    #[inline]
    pub fn local_direction(&self, p: Vec2) -> Vec3 {
        Vec3::new(
            -(2.0 * p.x / self.width as f32 - 1.0) * self.tan_half_x,
            -(2.0 * p.y / self.height as f32 - 1.0) * self.tan_half_y,
            1.0,
        )
    }

    /// World-space ray through film position `p`. It starts at the pinhole (Mitsuba starts at
    /// the near-clip plane; nothing is ever placed closer than that in practice) and ends at the
    /// far-clip plane.
    #[inline]
    pub fn generate_ray(&self, p: Vec2) -> Ray {
        let dl = self.local_direction(p);
        let dw = self.to_world.transform_vector3(dl);
        let len = dw.length();
        let d = dw / len;
        // far clip is measured along the optical axis (local z; dl.z = 1)
        let cos_axis = 1.0 / dl.length();
        Ray { o: self.origin, d, tmax: self.far_clip / cos_axis.max(1e-6) }
    }

    /// Film position (pixels) where the world point `p` projects, if it is in front of the
    /// camera and inside the film. Used by light tracing and de-lighting.
    pub fn project(&self, p: Vec3) -> Option<Vec2> {
        let local = self.world_to_camera.transform_point3(p);
        if local.z <= 0.0 {
            return None;
        }
        let x = local.x / local.z;
        let y = local.y / local.z;
        let px = (1.0 - x / self.tan_half_x) * 0.5 * self.width as f32;
        let py = (1.0 - y / self.tan_half_y) * 0.5 * self.height as f32;
        (px >= 0.0 && py >= 0.0 && px < self.width as f32 && py < self.height as f32)
            .then_some(Vec2::new(px, py))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_ray_is_forward_and_project_inverts() {
        let d = SensorDesc {
            id: "c".into(),
            to_world: Mat4::look_at_rh(Vec3::new(0.0, 0.0, 3.9), Vec3::ZERO, Vec3::Y).inverse(),
            fov_x_deg: 40.0,
            width: 64,
            height: 48,
            near_clip: 1e-3,
            far_clip: 100.0,
            spp: None,
        };
        // glam's look_at_rh looks along -z; flip x and z to get Mitsuba's +z forward, +x left
        let mut d = d;
        d.to_world *= Mat4::from_scale(Vec3::new(-1.0, 1.0, -1.0));
        let cam = Camera::new(&d);
        let r = cam.generate_ray(Vec2::new(32.0, 24.0));
        assert!((r.d - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-6);
        // pixel to the right of the centre looks to world +x (camera at +z looking to -z)
        let r = cam.generate_ray(Vec2::new(60.0, 24.0));
        assert!(r.d.x > 0.0);
        let r = cam.generate_ray(Vec2::new(32.0, 2.0));
        assert!(r.d.y > 0.0, "top row looks up");
        for (px, py) in [(0.5f32, 0.5f32), (10.25, 40.75), (63.5, 47.5)] {
            let r = cam.generate_ray(Vec2::new(px, py));
            let q = cam.project(r.at(2.0)).unwrap();
            assert!((q - Vec2::new(px, py)).length() < 1e-3, "{q:?}");
        }
    }
}
