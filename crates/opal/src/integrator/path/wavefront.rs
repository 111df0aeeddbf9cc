//! A row of the image rendered [`PACKET`] pixels at a time with the scalar vertex: lane `k`
//! renders one pixel's samples one after the other with the pixel's own generator and takes the
//! row's next pixel when it is done, so each pixel draws the same numbers in the same order and
//! adds the same terms in the same order as [`super::render_row_scalar`] — the image is **bit
//! for bit** that of the scalar loop.
//!
//! Per step, the lanes' rays are traced together ([`crate::accel::Accel::intersect8`]: the
//! packet kernel on tiny scenes, eight interleaved traversals on the BVH), then each lane with a
//! hit gets its vertex from [`super::vertex`] (any material, any light), then the pending shadow
//! rays are traced together ([`crate::accel::Accel::occluded8`]: the same answers as
//! [`Scene::occluded`]). All-diffuse scenes lit by triangles take [`super::wide_row`] instead
//! (the same bits, a structure-of-arrays path state and the wide vertex).
//!
//! Tests: `super::tests` (rows equal the scalar rows bit for bit, every plan).

use super::wide::Kernel;
use super::{PathSettings, PathState, PixelSums, Row};
use crate::accel::packet::{PACKET, PacketHits, RayPacket};
use crate::geometry::Ray;
use crate::light::Light;
use crate::math::{Vec2, Vec3};
use crate::sampling::Rng;
use crate::scene::{Material, Scene};
use crate::spectrum::Spectrum;

/// The wide kernel for scenes whose materials are all diffuse and whose lights are all emitting
/// triangles, with a light sampler ([`super::wide_row`]); `None` otherwise.
pub(super) fn wide_kernel(scene: &Scene, kernel: Kernel) -> Option<Kernel> {
    let diffuse = scene.shapes.iter().all(|sh| matches!(sh.material, Material::Diffuse { .. }));
    let triangles = scene.lights.iter().all(|l| matches!(l, Light::Triangle(_)));
    (diffuse && triangles && scene.light_sampler().is_some()).then_some(kernel)
}

/// Gives the lanes of `packet` not in `active` the origin and direction of an active lane and
/// `tmax = 0` (inactive). A default lane's zero direction would make every triangle test of the
/// packet kernel degenerate and send the lane to its exact scalar fallback (all triangles, one
/// by one), which costs more than the packet itself.
pub(super) fn fill_inactive(packet: &mut RayPacket, active: [bool; PACKET]) {
    let Some(a) = active.iter().position(|&b| b) else { return };
    let mut r = packet.ray(a);
    r.tmax = 0.0;
    for (k, &on) in active.iter().enumerate() {
        if !on {
            packet.set(k, &r);
        }
    }
}

/// A pixel being rendered in one lane.
struct Lane {
    x: usize,
    rng: Rng,
    sums: PixelSums,
    /// Samples started.
    started: u32,
    st: PathState,
    ray: Ray,
}

/// The shadow rays and contributions the lanes' vertices left pending.
struct Pending {
    rays: RayPacket,
    contrib: [Option<Spectrum>; PACKET],
}

/// Renders row `y` of camera `cam` into `row` (see the module docs).
pub(super) fn render_row(scene: &Scene, cam: usize, y: usize, s: &PathSettings, row: &mut Row) {
    let camera = &scene.cameras[cam];
    let w = camera.width;
    let accel = scene.accel();
    let mut next_x = 0usize;
    let start_sample = |lane: &mut Lane| {
        let p = Vec2::new(lane.x as f32 + lane.rng.next_f32(), y as f32 + lane.rng.next_f32());
        lane.ray = camera.generate_ray(p);
        lane.st = PathState::START;
        lane.started += 1;
    };
    let take_pixel = |next_x: &mut usize| -> Option<Lane> {
        if *next_x >= w || s.spp == 0 {
            return None;
        }
        let x = *next_x;
        *next_x += 1;
        let mut lane = Lane {
            x,
            rng: Rng::new(s.seed, cam as u64, (y * w + x) as u64),
            sums: PixelSums::default(),
            started: 0,
            st: PathState::START,
            ray: Ray::new(Vec3::ZERO, Vec3::Z),
        };
        start_sample(&mut lane);
        Some(lane)
    };
    let mut lanes: [Option<Lane>; PACKET] = std::array::from_fn(|_| take_pixel(&mut next_x));
    loop {
        let mut packet = RayPacket::default();
        let mut active = [false; PACKET];
        for (k, lane) in lanes.iter().enumerate() {
            if let Some(lane) = lane {
                packet.set(k, &lane.ray);
                active[k] = true;
            }
        }
        if !active.contains(&true) {
            break;
        }
        fill_inactive(&mut packet, active);
        let hits = accel.intersect8(&packet);
        let mut pending = Pending { rays: RayPacket::default(), contrib: [None; PACKET] };
        let mut ended = [false; PACKET];
        shade_scalar(scene, s, &mut lanes, &hits, &mut pending, &mut ended);
        let shadowed = pending.contrib.map(|c| c.is_some());
        if shadowed.contains(&true) {
            fill_inactive(&mut pending.rays, shadowed);
            let blocked = accel.occluded8(&pending.rays);
            for (k, c) in pending.contrib.iter().enumerate() {
                if let (Some(c), Some(lane)) = (c, &mut lanes[k])
                    && blocked >> k & 1 == 0
                {
                    lane.st.l += *c;
                }
            }
        }
        for (k, slot) in lanes.iter_mut().enumerate() {
            if !ended[k] {
                continue;
            }
            let Some(lane) = slot else { continue };
            lane.sums.add(lane.st.l);
            if lane.started < s.spp {
                start_sample(lane);
            } else {
                row.put(lane.x, &lane.sums);
                *slot = take_pixel(&mut next_x);
            }
        }
    }
}

/// [`super::vertex`] lane by lane.
fn shade_scalar(
    scene: &Scene,
    s: &PathSettings,
    lanes: &mut [Option<Lane>; PACKET],
    hits: &PacketHits,
    pending: &mut Pending,
    ended: &mut [bool; PACKET],
) {
    for (k, slot) in lanes.iter_mut().enumerate() {
        let Some(lane) = slot else { continue };
        if hits.prim[k] < 0 {
            super::escaped(scene, s, &mut lane.st, &lane.ray);
            ended[k] = true;
            continue;
        }
        let si = scene.interaction_at(&lane.ray, hits.prim[k] as u32, hits.t[k], hits.b1[k], hits.b2[k]);
        let (shadow, next) = super::vertex(scene, s, &mut lane.st, &lane.ray, &si, &mut lane.rng);
        if let Some(sh) = shadow {
            pending.rays.set(k, &sh.ray);
            pending.contrib[k] = Some(sh.contrib);
        }
        match next {
            Some(r) => lane.ray = r,
            None => ended[k] = true,
        }
    }
}
