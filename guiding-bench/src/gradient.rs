//! NPM's loss gradient `∇_y ln q(ω)` of 8 vMF lobes over a batch: the
//! vectorised kernel the training runs
//! ([`grad_log_pdf_vmf_batch`]) against the per-sample reference
//! ([`VmfMixture::grad_log_pdf`]), one thread.

use crate::inputs::{directions, BATCH};
use guiding_core::glam::Vec3;
use guiding_core::mixture::vmf::{VmfMixture, VMF_RAW_PER_LOBE};
use guiding_core::model::npm::{NPM_LOBES, NPM_OUTPUTS};
use guiding_core::model::vmf_gradient::grad_log_pdf_vmf_batch;
use guiding_core::rng::Rng;
use std::hint::black_box;

/// Raw outputs, directions and gradient buffers of [`BATCH`] samples.
pub struct VmfGradientWorkload {
    ys: Vec<[f32; NPM_OUTPUTS]>,
    dirs: Vec<Vec3>,
    dys: Vec<[f32; NPM_OUTPUTS]>,
    log_pdfs: Vec<f32>,
}

impl VmfGradientWorkload {
    /// Raw outputs uniform in `[−3, 3)`, directions uniform on the sphere.
    #[must_use]
    pub fn new() -> Self {
        let mut rng = Rng::new(31);
        Self {
            ys: (0..BATCH)
                .map(|_| core::array::from_fn(|_| 6.0 * rng.next_f32() - 3.0))
                .collect(),
            dirs: directions(37, BATCH),
            dys: vec![[0.0; NPM_OUTPUTS]; BATCH],
            log_pdfs: vec![0.0; BATCH],
        }
    }

    /// Samples per pass.
    #[must_use]
    pub fn len(&self) -> usize {
        self.ys.len()
    }

    /// Whether there are none (never: [`BATCH`] samples).
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.ys.is_empty()
    }

    /// The batched kernel over every sample.
    pub fn batched(&mut self) {
        grad_log_pdf_vmf_batch(
            black_box(&self.ys),
            &self.dirs,
            &mut self.dys,
            &mut self.log_pdfs,
        );
        black_box(&self.dys);
    }

    /// The per-sample reference over every sample; returns a sum of the
    /// results so that nothing is optimised away.
    pub fn per_sample(&self) -> f32 {
        let mut acc = 0.0f32;
        for (y, &d) in self.ys.iter().zip(&self.dirs) {
            let raw: [[f32; VMF_RAW_PER_LOBE]; NPM_LOBES] =
                core::array::from_fn(|k| core::array::from_fn(|r| y[k * VMF_RAW_PER_LOBE + r]));
            let mut g = [[0.0f32; VMF_RAW_PER_LOBE]; NPM_LOBES];
            acc += VmfMixture::grad_log_pdf(&raw, black_box(d), &mut g) + g[0][0];
        }
        acc
    }
}

impl Default for VmfGradientWorkload {
    fn default() -> Self {
        Self::new()
    }
}
