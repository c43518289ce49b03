//! Training records of a block's paths, through the library's recorder.
//!
//! The wavefront learns a vertex in three steps (its hit and emission, then its NEE, then its
//! continuation), so the driver fills each slot's last vertex as the stages run and hands the
//! finished paths to `guiding`'s recorder, whose propagation rule (emission in full for the
//! training target, MIS-weighted for the path estimate) makes the training samples.

use glam::Vec3;
use guiding::{PathRecorder, PathVertex};
use guiding_core::sample::TrainingSample;

/// Where a continuing vertex is and how it scattered.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Scatter {
    pub position: Vec3,
    pub normal: Vec3,
    pub wo: Vec3,
    pub roughness: f32,
    pub wi: Vec3,
    /// Density of `wi` (the strategy's combined density).
    pub sample_pdf: f32,
    pub bsdf_pdf: f32,
    pub bsdf_cos: Vec3,
    /// The continuation weight `f·|cos|/p` (used when the vertex is not trainable).
    pub weight: Vec3,
    pub trainable: bool,
}

/// Records the paths of one block, sample by sample.
#[derive(Default)]
pub(crate) struct BlockRecorder {
    chains: Vec<Vec<PathVertex>>,
    escaped: Vec<(Vec3, f32)>,
    /// Russian-roulette factor `1/q` of each slot's last vertex.
    rr: Vec<f32>,
    recorder: PathRecorder,
}

impl BlockRecorder {
    /// Starts `paths` empty paths.
    pub(crate) fn start(&mut self, paths: usize) {
        self.chains.resize_with(paths, Vec::new);
        self.chains.truncate(paths);
        self.chains.iter_mut().for_each(Vec::clear);
        self.escaped.clear();
        self.escaped.resize(paths, (Vec3::ZERO, 1.0));
        self.rr.clear();
        self.rr.resize(paths, 1.0);
    }

    /// A new vertex of path `slot` with the emission seen there and its MIS weight.
    pub(crate) fn hit(&mut self, slot: u32, emitted: Vec3, mis_weight: f32) {
        self.rr[slot as usize] = 1.0;
        self.chains[slot as usize].push(PathVertex {
            emitted: emitted.to_array(),
            emitted_mis_weight: mis_weight,
            ..PathVertex::default()
        });
    }

    /// The ray of path `slot` left the scene and found `radiance` (MIS weight `mis_weight`).
    pub(crate) fn escaped(&mut self, slot: u32, radiance: Vec3, mis_weight: f32) {
        self.escaped[slot as usize] = (radiance, mis_weight);
    }

    /// The last vertex of `slot` survived Russian roulette with probability `1 / inv_q`.
    pub(crate) fn roulette(&mut self, slot: u32, inv_q: f32) {
        self.rr[slot as usize] = inv_q;
    }

    /// NEE at the last vertex of `slot` added `local` (without the path throughput).
    pub(crate) fn direct(&mut self, slot: u32, local: Vec3) {
        let s = self.rr[slot as usize];
        if let Some(v) = self.chains[slot as usize].last_mut() {
            v.direct = (Vec3::from_array(v.direct) + local * s).to_array();
        }
    }

    /// The last vertex of `slot` continued the path.
    pub(crate) fn scatter(&mut self, slot: u32, s: &Scatter) {
        let rr = self.rr[slot as usize];
        let Some(v) = self.chains[slot as usize].last_mut() else {
            return;
        };
        v.position = s.position.to_array();
        v.normal = s.normal.to_array();
        v.wo = s.wo.to_array();
        v.roughness = s.roughness;
        v.wi = s.wi.to_array();
        v.continuation_scale = rr;
        if s.trainable {
            v.sample_pdf = s.sample_pdf;
            v.bsdf_pdf = s.bsdf_pdf;
            v.bsdf_cos = s.bsdf_cos.to_array();
        } else {
            // Not guided here (delta, near-specular): only the weight propagates.
            v.sample_pdf = 1.0;
            v.bsdf_cos = s.weight.to_array();
            v.is_delta = true;
        }
    }

    /// Propagates every path of the sample (slot order) and appends the training samples.
    pub(crate) fn end(&mut self, out: &mut Vec<TrainingSample>) {
        for (chain, &(esc, w)) in self.chains.iter().zip(&self.escaped) {
            self.recorder.start_path();
            for v in chain {
                self.recorder.add_vertex(*v);
            }
            if esc != Vec3::ZERO {
                self.recorder.add_escaped_radiance(esc.to_array(), w);
            }
            self.recorder.end_path();
        }
        out.extend_from_slice(self.recorder.samples());
        self.recorder.clear_samples();
    }
}
