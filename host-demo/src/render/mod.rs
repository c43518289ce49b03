//! Rendering: the [`options`], the pass [`schedule`], the one [`wavefront`] driver with its
//! typed [`queues`] and direction-sampling [`strategy`], the [`image`]s it makes, their
//! [`output`] and [`compare`]ison, and the entry points [`render`] and [`render_guided`].
//!
//! Modules depend downwards: the entry points here → [`wavefront`] → [`strategy`] →
//! [`queues`], [`schedule`], [`options`] → [`crate::scene`].

pub mod compare;
pub mod image;
pub mod options;
pub mod output;
pub mod queues;
pub mod roulette;
pub mod schedule;
pub mod strategy;
pub mod wavefront;

pub use image::{Image, RenderStats};
pub use options::{IntegratorKind, RenderOptions, Roulette};
pub use roulette::RouletteStats;
#[cfg(feature = "testing")]
pub use strategy::guided::TestHooks;
pub use strategy::guided::{CacheMode, GuidedOptions, GuidedStats, PassWeightStats, TrialStats};
pub use strategy::probe::ProbeStats;

use crate::scene::Scene;
use guiding::{GuidingError, GuidingField};
use strategy::bsdf::BsdfSampling;
use strategy::guided::Guided;

/// Renders `scene` with `pt` or `pt-nee` (`opts.integrator`).
pub fn render(scene: &Scene, opts: &RenderOptions) -> Image {
    render_with_stats(scene, opts).0
}

/// [`render`], and what the render did.
///
/// The image is bit-identical for any thread count and block size.
pub fn render_with_stats(scene: &Scene, opts: &RenderOptions) -> (Image, RenderStats) {
    let nee = opts.integrator == IntegratorKind::PtNee;
    match wavefront::render_passes(scene, opts, nee, &mut BsdfSampling) {
        Ok(r) => r,
        Err(never) => match never {},
    }
}

/// What the library's thin-medium rule ([`guiding::media`]) says about one medium of a scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MediumGuiding {
    /// Its scattering optical depth `τ_s = σ_s,max · d` ([`guiding::media::scattering_depth`]).
    pub scattering_depth: f32,
    /// `d`: the diagonal of the region it fills ([`Scene::medium_extent`]).
    pub extent: f32,
    /// `τ_s ≥` [`guiding::media::MIN_GUIDED_SCATTERING_DEPTH`]: its scattering points are
    /// guided (with [`GuidedOptions::guide_media`]); else they sample the phase function and
    /// make no training samples.
    pub guided: bool,
}

/// [`MediumGuiding`] of every medium of `scene`, in order.
pub fn media_guiding(scene: &Scene) -> Vec<MediumGuiding> {
    (0..scene.media.len())
        .map(|m| {
            let extent = scene.medium_extent(m as u32);
            let sigma = scene.media[m].max_scattering();
            MediumGuiding {
                scattering_depth: guiding::media::scattering_depth(sigma, extent).unwrap_or(0.0),
                extent,
                guided: guiding::media::guides_medium(sigma, extent),
            }
        })
        .collect()
}

/// Renders `scene` with guided path tracing, training `guide` online as the library's
/// schedule (`gopts.schedule`) says. `opts.integrator` is ignored (NEE follows
/// `gopts.nee`). The guide runs where it was put: on the CPU threads, or on a Vulkan device
/// ([`GuidingField::use_device`], `--device gpu`), through the same calls.
///
/// # Errors
/// The guide's device failed (only a guide on a device that does not fall back to the
/// CPU): the render stops after the pass it happened in. Schedule options out of range.
pub fn render_guided(
    scene: &Scene,
    opts: &RenderOptions,
    gopts: &GuidedOptions,
    guide: &mut GuidingField,
) -> Result<(Image, GuidedStats), GuidingError> {
    // The efficiency trial weighs time: only a time budget asks that question. Without NEE
    // its unguided arm is BSDF sampling alone, whose trial passes cost the image far more
    // than they can save on a scene with small emitters (see `GuidedOptions`).
    // The library's thin-medium rule, per medium (see `media_guiding`).
    let media_guided: Vec<bool> = media_guiding(scene)
        .iter()
        .map(|m| gopts.guides_medium(m))
        .collect();
    let guided_media = media_guided.contains(&true);
    let gopts = GuidedOptions {
        efficiency_trial: gopts.efficiency_trial
            && opts.time_budget.is_some()
            && gopts.nee
            && scene.has_samplable_emitter(),
        // Measured in both media scenes (docs/bench-2026-12-07-media): the per-cell selection
        // fit chooses c = 0 nearly everywhere, also with the phase lobes weighed (relMSE
        // 1.07x / 0.83x pt-nee against 0.57x / 0.37x without it), and the cosine product
        // (the cache's product lanes, with the lanes without a surface for the medium
        // vertices) brings nothing within the seed spread at 14 % fewer samples: both off.
        cosine_product: gopts.cosine_product && !guided_media,
        fit_selection: gopts.fit_selection && !guided_media,
        ..*gopts
    };
    let budget = match opts.time_budget {
        Some(t) => guiding::Budget::Seconds(t.as_secs_f64()),
        None => guiding::Budget::Spp(opts.spp),
    };
    let mut strategy = Guided::new(guide, &gopts, budget, media_guided)?;
    let (img, rs) = wavefront::render_passes(scene, opts, gopts.nee, &mut strategy)?;
    Ok((img, strategy.finish(&rs)))
}
