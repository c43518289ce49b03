//! Rendering: the [`options`], the pass [`schedule`], the one [`wavefront`] driver with its
//! typed [`queues`] and direction-sampling [`strategy`], the [`image`]s it makes, their
//! [`output`] and [`compare`]ison.

pub mod compare;
pub mod image;
pub mod options;
pub mod output;
pub mod queues;
mod record;
pub mod schedule;
pub mod strategy;
pub mod wavefront;

pub use image::Image;
pub use options::{IntegratorKind, RenderOptions};
pub use strategy::guided::{render_guided, render_guided_gpu, GuidedOptions, GuidedStats};
pub use wavefront::RenderStats;

use crate::scene::Scene;
use strategy::bsdf::BsdfSampling;

/// Renders `scene` with `pt` or `pt-nee` (`opts.integrator`).
pub fn render(scene: &Scene, opts: &RenderOptions) -> Image {
    render_with_stats(scene, opts).0
}

/// [`render`], and what the render did.
///
/// The image is bit-identical for any thread count and block size.
pub fn render_with_stats(scene: &Scene, opts: &RenderOptions) -> (Image, RenderStats) {
    let nee = opts.integrator == IntegratorKind::PtNee;
    match wavefront::render_passes(scene, opts, nee, 0.0, &mut BsdfSampling) {
        Ok(r) => r,
        Err(never) => match never {},
    }
}
