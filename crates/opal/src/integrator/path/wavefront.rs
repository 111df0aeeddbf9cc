//! A row of the image rendered [`PACKET`] pixels at a time: lane `k` renders one pixel's samples
//! one after the other with the pixel's own generator and takes the row's next pixel when it is
//! done, so each pixel draws the same numbers in the same order and adds the same terms in the
//! same order as [`super::render_row_scalar`] — the image is **bit for bit** that of the scalar
//! loop, whatever the shading and tracing chosen here.
//!
//! Per step, the lanes' rays are traced together ([`crate::accel::Accel::intersect8`]: the packet kernel on
//! tiny scenes, eight interleaved traversals on the BVH), then each lane with a hit gets its
//! vertex ([`Shading`]):
//! * [`Shading::Scalar`]: [`super::vertex`] lane by lane (any material, any light);
//! * [`Shading::Wide`]: on all-diffuse scenes lit by emitting triangles, the lane-parallel
//!   kernel of [`super::wide`] for the eight lanes at once; the gathers, the emission found at a
//!   hit, texture lookups, the light choice, the random numbers and the Russian roulette stay
//!   scalar per lane.
//!
//! Then the pending shadow rays are traced together ([`crate::accel::Accel::occluded8`]: the same answers as
//! [`Scene::occluded`]).
//!
//! Tests: `super::tests` (rows equal the scalar rows bit for bit, every combination).

use super::wide::{self, Kernel, VertexIn};
use super::{PathSettings, PathState, PixelSums, Row, emission};
use crate::accel::packet::{PACKET, PacketHits, RayPacket};
use crate::geometry::Ray;
use crate::light::Light;
use crate::math::{Vec2, Vec3};
use crate::sampling::Rng;
use crate::scene::{Material, Scene};
use crate::spectrum::Spectrum;

/// How the lanes' vertices are shaded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Shading {
    /// [`super::vertex`] lane by lane.
    Scalar,
    /// [`super::wide::vertex8`] (diffuse scenes lit by triangles; see [`wide_shading`]).
    Wide(Kernel),
}

/// The wide shading when every material of the scene is diffuse, every light an emitting
/// triangle, and there is a light sampler; `None` otherwise.
pub(super) fn wide_shading(scene: &Scene, kernel: Kernel) -> Option<Shading> {
    let diffuse = scene.shapes.iter().all(|sh| matches!(sh.material, Material::Diffuse { .. }));
    let triangles = scene.lights.iter().all(|l| matches!(l, Light::Triangle(_)));
    (diffuse && triangles && scene.light_sampler().is_some()).then_some(Shading::Wide(kernel))
}

/// Gives the lanes of `packet` not in `active` the origin and direction of an active lane and
/// `tmax = 0` (inactive). A default lane's zero direction would make every triangle test of the
/// packet kernel degenerate and send the lane to its exact scalar fallback (all triangles, one
/// by one), which costs more than the packet itself.
fn fill_inactive(packet: &mut RayPacket, active: [bool; PACKET]) {
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
pub(super) fn render_row(
    scene: &Scene,
    cam: usize,
    y: usize,
    s: &PathSettings,
    row: &mut Row,
    shading: Shading,
) {
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
    let mut inp = VertexIn::default();
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
        match shading {
            Shading::Scalar => shade_scalar(scene, s, &mut lanes, &hits, &mut pending, &mut ended),
            Shading::Wide(kernel) => {
                shade_wide(scene, s, &mut lanes, &hits, &mut pending, &mut ended, kernel, &mut inp)
            }
        }
        let shadowed = pending.contrib.map(|c| c.is_some());
        if shadowed.contains(&true) {
            fill_inactive(&mut pending.rays, shadowed);
            let blocked = accel.occluded8(&pending.rays);
            for (k, c) in pending.contrib.iter().enumerate() {
                if let (Some(c), Some(lane)) = (c, &mut lanes[k]) {
                    if blocked >> k & 1 == 0 {
                        lane.st.l += *c;
                    }
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

/// The wide kernel for the lanes that reach a scattering vertex (see the module docs).
#[allow(clippy::too_many_arguments)]
fn shade_wide(
    scene: &Scene,
    s: &PathSettings,
    lanes: &mut [Option<Lane>; PACKET],
    hits: &PacketHits,
    pending: &mut Pending,
    ended: &mut [bool; PACKET],
    kernel: Kernel,
    inp: &mut VertexIn,
) {
    let sampler = scene.light_sampler().expect("wide shading needs a light sampler");
    inp.active = [0; PACKET];
    let mut p = [Vec3::ZERO; PACKET];
    let mut any = false;
    for (k, slot) in lanes.iter_mut().enumerate() {
        let Some(lane) = slot else { continue };
        if hits.prim[k] < 0 {
            ended[k] = true;
            continue;
        }
        let si = scene.interaction_at(&lane.ray, hits.prim[k] as u32, hits.t[k], hits.b1[k], hits.b2[k]);
        let depth = emission(scene, s, &mut lane.st, &lane.ray, &si);
        if s.max_depth >= 0 && depth >= s.max_depth {
            ended[k] = true;
            continue;
        }
        let Material::Diffuse { reflectance, two_sided } = &scene.shapes[si.shape as usize].material else {
            unreachable!("wide shading runs on diffuse scenes only")
        };
        // the scalar vertex's draws, in its order: light choice, light sample, BSDF sample
        let rng = &mut lane.rng;
        let (idx, pmf, _) = sampler.sample(rng.next_f32());
        let ul = rng.next_2d();
        let _uc = rng.next_f32();
        let ub = rng.next_2d();
        let Light::Triangle(t) = &scene.lights[idx] else {
            unreachable!("wide shading: triangle lights only")
        };
        inp.active[k] = u32::MAX;
        inp.wo.set(k, (-lane.ray.d).to_array());
        inp.p.set(k, si.p.to_array());
        inp.ng.set(k, si.ng.to_array());
        inp.ns.set(k, si.ns.to_array());
        inp.two_sided[k] = if *two_sided { u32::MAX } else { 0 };
        inp.albedo.set(k, reflectance.eval(si.uv).0);
        inp.beta.set(k, lane.st.beta.0);
        inp.l0.set(k, t.p[0].to_array());
        inp.l1.set(k, t.p[1].to_array());
        inp.l2.set(k, t.p[2].to_array());
        inp.ln.set(k, t.n.to_array());
        inp.larea[k] = t.area;
        inp.lrad.set(k, t.radiance.0);
        inp.pmf[k] = pmf;
        inp.ul[0][k] = ul.x;
        inp.ul[1][k] = ul.y;
        inp.ub[0][k] = ub.x;
        inp.ub[1][k] = ub.y;
        p[k] = si.p;
        any = true;
    }
    if !any {
        return;
    }
    let out = wide::vertex8(inp, kernel);
    for (k, slot) in lanes.iter_mut().enumerate() {
        if inp.active[k] == 0 {
            continue;
        }
        let Some(lane) = slot else { continue };
        if out.shadow[k] != 0 {
            let ray = Ray {
                o: Vec3::from_array(out.so.get(k)),
                d: Vec3::from_array(out.sd.get(k)),
                tmax: out.stmax[k],
            };
            pending.rays.set(k, &ray);
            pending.contrib[k] = Some(Spectrum(out.contrib.get(k)));
        }
        if out.next[k] == 0 {
            ended[k] = true;
            continue;
        }
        let st = &mut lane.st;
        st.beta = Spectrum(out.beta.get(k));
        st.prev = Some((p[k], out.pdf[k], false));
        lane.ray = Ray::new(Vec3::from_array(out.no.get(k)), Vec3::from_array(out.nd.get(k)));
        // Russian roulette, as in the scalar vertex (η = 1: `eta_scale` is unchanged)
        if s.rr_depth >= 0 && st.depth >= s.rr_depth {
            let q = (st.beta.max_component() * st.eta_scale).min(0.95);
            if lane.rng.next_f32() >= q {
                ended[k] = true;
                continue;
            }
            st.beta /= q;
        }
    }
}
