//! BSDF sampling: the strategy of `pt` and `pt-nee`.

use super::{PassSamples, Strategy, Traced, VertexStrategy};
use crate::math::{Frame, Rng};
use crate::render::queues::{Continuations, LightSamples, Vertices};
use crate::render::schedule::Pass;
use crate::scene::bsdf::Material;
use crate::scene::Scene;

/// Continues every path by sampling its BSDF; NEE's MIS partner is the BSDF density.
#[derive(Clone, Copy, Debug, Default)]
pub struct BsdfSampling;

impl Strategy for BsdfSampling {
    type Worker<'a> = BsdfSampling;
    type Report = ();
    type Error = std::convert::Infallible;

    fn worker(&self) -> BsdfSampling {
        BsdfSampling
    }

    fn report(&self, _: BsdfSampling) {}

    fn begin_pass(&mut self, _: &Pass) -> bool {
        false
    }

    fn end_chunk(
        &mut self,
        _: &Pass,
        _: bool,
        _: Vec<()>,
        _: PassSamples,
        _: Traced,
    ) -> Result<(), Self::Error> {
        Ok(())
    }
}

impl VertexStrategy for BsdfSampling {
    fn prepare(&mut self, _: &Scene, _: &Vertices, _: &mut [Rng]) {}

    fn light_pdfs(&mut self, _: &Vertices, lights: &mut LightSamples) {
        lights.sampling_pdf.clear();
        lights.sampling_pdf.extend_from_slice(&lights.bsdf_pdf);
    }

    fn trains(&self, _: &Material, _: u32) -> bool {
        false
    }

    fn sample(&mut self, verts: &Vertices, rng: &mut [Rng], out: &mut Continuations) {
        for i in 0..verts.len() {
            sample_bsdf(verts, i, &mut rng[verts.slot[i] as usize], out);
        }
    }
}

/// Samples the BSDF of vertex `i` into `out` (three numbers from `rng`).
#[inline]
pub(crate) fn sample_bsdf(verts: &Vertices, i: usize, rng: &mut Rng, out: &mut Continuations) {
    let (u0, u1, u2) = (rng.next_f32(), rng.next_f32(), rng.next_f32());
    let frame = Frame::from_z(verts.ns[i]);
    // The host's BSDFs take Mitsuba's argument names: their `wi` is the driver's `wo`.
    if let Some(bs) = verts.bsdf[i].sample(frame.to_local(verts.wo[i]), u0, u1, u2) {
        let wi = frame.to_world(bs.wo).normalize();
        out.set(i, wi, bs.weight, bs.pdf);
    }
}
