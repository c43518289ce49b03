//! The wavefront path recorder (`guiding::BatchRecorder`) against the
//! one-path-at-a-time `PathRecorder` and against the propagation rule of the
//! recorder docs written out here a second time.
//!
//! Random blocks of paths (seeded PCG: escapes, Russian-roulette scales,
//! delta vertices, paths that end early or have no vertex, NaN / infinite /
//! negative inputs, calls for slots that do not exist) are recorded bounce
//! by bounce with the slots in a new random order at every stage, as a
//! wavefront renderer would, and compared **bit for bit**: the training
//! samples (bytes, in slot order) and `L̃_o(0)` of every slot. The negative
//! control shows that the same comparison flags a propagation that differs
//! from the documented one (MIS-weighted emission as the target; the
//! roulette scale left out).

use guiding::{
    BatchRecorder, Continuation, GuidingConfig, GuidingField, ModelSize, PathRecorder, PathVertex,
    TrainingSample,
};
use guiding_core::sphere::square_to_uniform_sphere;
use guiding_tests::rng::Pcg32;

/// One hit of a path, as the renderer learns it over the bounce.
#[derive(Clone, Debug)]
struct Hit {
    /// What is known at the intersection (sometimes with `direct` or a
    /// `continuation_scale` already set).
    vertex: PathVertex,
    /// Russian-roulette factors, given before the continuation is sampled
    /// (`scale_first`) or after.
    scales: Vec<f32>,
    scale_first: bool,
    /// Unoccluded shadow rays, in order.
    direct: Vec<[f32; 3]>,
    continuation: Option<Continuation>,
}

/// One path of a block: its hits, then what escaped along the last `wi`
/// (or, without hits, what the camera ray saw).
#[derive(Clone, Debug, Default)]
struct Path {
    hits: Vec<Hit>,
    escapes: Vec<([f32; 3], f32)>,
}

impl Hit {
    /// The vertex as a `PathRecorder` is given it: every later call applied,
    /// in the order the `BatchRecorder` applies them.
    fn complete(&self) -> PathVertex {
        let mut v = self.vertex;
        for d in &self.direct {
            for (sum, x) in v.direct.iter_mut().zip(d) {
                *sum += x;
            }
        }
        if let Some(k) = self.continuation {
            (v.wi, v.sample_pdf, v.bsdf_pdf, v.bsdf_cos) =
                (k.wi, k.sample_pdf, k.bsdf_pdf, k.bsdf_cos);
        }
        for s in &self.scales {
            v.continuation_scale *= s;
        }
        v
    }
}

/// A value drawn by `draw`, or now and then (`1/50`) one a renderer should
/// not produce.
fn value(rng: &mut Pcg32, draw: impl FnOnce(&mut Pcg32) -> f32) -> f32 {
    if rng.next_u32() % 50 == 0 {
        [f32::NAN, f32::INFINITY, -1.0][(rng.next_u32() % 3) as usize]
    } else {
        draw(rng)
    }
}

fn rgb(rng: &mut Pcg32, max: f32) -> [f32; 3] {
    let mut c = [0.0; 3];
    for x in &mut c {
        *x = value(rng, |r| r.uniform(0.0, max));
    }
    c
}

fn unit(rng: &mut Pcg32) -> [f32; 3] {
    square_to_uniform_sphere(rng.next_vec2()).to_array()
}

fn chance(rng: &mut Pcg32, p: f32) -> bool {
    rng.next_f32() < p
}

fn random_hit(rng: &mut Pcg32, first: bool, last: bool) -> Hit {
    let emits = chance(rng, 0.3);
    let vertex = PathVertex {
        position: [
            rng.uniform(-1.0, 1.0),
            rng.uniform(-2.0, 2.0),
            rng.uniform(0.0, 3.0),
        ],
        normal: unit(rng),
        wo: unit(rng),
        roughness: rng.next_f32(),
        emitted: if emits { rgb(rng, 5.0) } else { [0.0; 3] },
        emitted_mis_weight: if first {
            1.0
        } else {
            value(rng, |r| r.next_f32())
        },
        direct: if chance(rng, 0.2) {
            rgb(rng, 0.5)
        } else {
            [0.0; 3]
        },
        continuation_scale: if chance(rng, 0.1) { 1.5 } else { 1.0 },
        is_delta: chance(rng, 0.2),
        ..PathVertex::default()
    };
    let scales = (0..rng.next_u32() % 3)
        .map(|_| value(rng, |r| 1.0 / r.uniform(0.25, 1.0)))
        .collect();
    let direct = (0..rng.next_u32() % 4).map(|_| rgb(rng, 1.0)).collect();
    // Every hit but the last continues (now and then with pdf 0 all the
    // same: a vertex that ended its path, followed by more); the last one
    // continues (into an escape or nothing) or ends the path.
    let continues = if last {
        chance(rng, 0.5)
    } else {
        !chance(rng, 0.05)
    };
    let continuation = continues.then(|| Continuation {
        wi: unit(rng),
        sample_pdf: value(rng, |r| r.uniform(0.05, 3.0)),
        bsdf_pdf: rng.uniform(0.0, 2.0),
        bsdf_cos: rgb(rng, 1.0),
    });
    Hit {
        vertex,
        scales,
        scale_first: chance(rng, 0.5),
        direct,
        continuation,
    }
}

fn random_block(rng: &mut Pcg32) -> Vec<Path> {
    let n = match rng.next_u32() % 8 {
        0 => 0,
        1 => 1,
        _ => 2 + rng.next_u32() % 40,
    };
    (0..n)
        .map(|_| {
            let len = if chance(rng, 0.15) {
                0
            } else {
                1 + rng.next_u32() % 6
            };
            let hits = (0..len)
                .map(|k| random_hit(rng, k == 0, k + 1 == len))
                .collect();
            let escapes = if chance(rng, 0.6) {
                (0..1 + rng.next_u32() % 2)
                    .map(|_| (rgb(rng, 4.0), value(rng, |r| r.next_f32())))
                    .collect()
            } else {
                Vec::new()
            };
            Path { hits, escapes }
        })
        .collect()
}

/// The slots `0 … n−1` in a random order.
fn shuffled(rng: &mut Pcg32, n: usize) -> Vec<u32> {
    let mut order: Vec<u32> = (0..n as u32).collect();
    for i in (1..n).rev() {
        order.swap(i, rng.next_u32() as usize % (i + 1));
    }
    order
}

/// Records `paths` as a wavefront renderer would: per bounce the escapes of
/// the rays that left the scene, the hits (with roulette), the shadow rays,
/// the continuations, each stage over the slots in a new random order, with
/// calls for slots that are not there in between. Returns the calls that
/// had to be ignored.
fn record_wavefront(rec: &mut BatchRecorder, paths: &[Path], rng: &mut Pcg32) -> u64 {
    let n = paths.len();
    rec.start(n);
    let bogus = n as u32 + rng.next_u32() % 3;
    let mut ignored = 0;
    let depth = paths.iter().map(|p| p.hits.len()).max().unwrap_or(0);
    for b in 0..=depth {
        for slot in shuffled(rng, n) {
            let p = &paths[slot as usize];
            if p.hits.len() == b {
                for &(radiance, w) in &p.escapes {
                    assert!(rec.add_escaped_radiance(slot, radiance, w));
                }
            }
        }
        for slot in shuffled(rng, n) {
            if let Some(h) = paths[slot as usize].hits.get(b) {
                assert!(rec.add_vertex(slot, h.vertex));
                if h.scale_first {
                    for &s in &h.scales {
                        assert!(rec.scale_continuation(slot, s));
                    }
                }
            } else if b == 0 {
                // A slot without a vertex has nothing to fill in.
                assert!(!rec.add_direct(slot, [1.0; 3]));
                ignored += 1;
            }
        }
        assert!(!rec.add_vertex(bogus, PathVertex::default()));
        assert!(!rec.add_escaped_radiance(u32::MAX, [1.0; 3], 1.0));
        ignored += 2;
        for round in 0..3 {
            for slot in shuffled(rng, n) {
                let hit = paths[slot as usize].hits.get(b);
                if let Some(&d) = hit.and_then(|h| h.direct.get(round)) {
                    assert!(rec.add_direct(slot, d));
                }
            }
        }
        assert!(!rec.add_direct(bogus, [1.0; 3]));
        ignored += 1;
        for slot in shuffled(rng, n) {
            let Some(h) = paths[slot as usize].hits.get(b) else {
                continue;
            };
            if let Some(k) = h.continuation {
                assert!(rec.set_continuation(slot, k));
            }
            if !h.scale_first {
                for &s in &h.scales {
                    assert!(rec.scale_continuation(slot, s));
                }
            }
        }
        assert!(!rec.set_continuation(bogus, Continuation::default()));
        assert!(!rec.scale_continuation(bogus, 2.0));
        ignored += 2;
    }
    ignored
}

/// Each path alone through a `PathRecorder`, in slot order: its samples
/// (appended to `rec`) and `L̃_o(0)` per path.
fn record_one_by_one(rec: &mut PathRecorder, paths: &[Path]) -> Vec<[f32; 3]> {
    paths
        .iter()
        .map(|p| {
            rec.start_path();
            for h in &p.hits {
                rec.add_vertex(h.complete());
            }
            for &(radiance, w) in &p.escapes {
                rec.add_escaped_radiance(radiance, w);
            }
            rec.end_path()
        })
        .collect()
}

/// A propagation rule: the documented one, or a defect for the negative
/// control.
#[derive(Clone, Copy, PartialEq, Debug)]
enum Rule {
    Documented,
    /// The target of vertex `k` takes the emission at `k + 1` MIS-weighted.
    MisWeightedTarget,
    /// The Russian-roulette scale is left out of the continuation weight.
    NoRoulette,
}

/// The recorder docs' rule written out again, per channel: `L̃_o(k) = w_k
/// L_e(k) + D_k + β_k L̃_i(k)` for the estimate, `L_e(k+1)` in full in the
/// target, no sample for delta vertices or `sample_pdf ≤ 0`. Walks the path
/// backwards, calling `at_sample(vertex, target, L̃_i)` at each vertex that
/// makes a sample; returns `L̃_o(0)`.
fn walk_by_the_rule(
    p: &Path,
    rule: Rule,
    mut at_sample: impl FnMut(&PathVertex, [f32; 3], [f32; 3]),
) -> [f32; 3] {
    let (mut target, mut estimate) = ([0.0f32; 3], [0.0f32; 3]);
    for (radiance, w) in &p.escapes {
        for c in 0..3 {
            target[c] += radiance[c];
            estimate[c] += radiance[c] * w;
        }
    }
    for h in p.hits.iter().rev() {
        let v = h.complete();
        let continues = v.sample_pdf > 0.0;
        if continues && !v.is_delta {
            at_sample(&v, target, estimate);
        }
        let s = if rule == Rule::NoRoulette {
            1.0
        } else {
            v.continuation_scale
        };
        for c in 0..3 {
            let scattered = if continues {
                v.bsdf_cos[c] * (s / v.sample_pdf) * estimate[c]
            } else {
                0.0
            };
            let rest = v.direct[c] + scattered;
            let weighted = v.emitted[c] * v.emitted_mis_weight + rest;
            target[c] = if rule == Rule::MisWeightedTarget {
                weighted
            } else {
                v.emitted[c] + rest
            };
            estimate[c] = weighted;
        }
    }
    estimate
}

/// [`walk_by_the_rule`]: appends the path's samples to `out` in path order,
/// returns `L̃_o(0)`.
fn by_the_rule(p: &Path, rule: Rule, out: &mut Vec<TrainingSample>) -> [f32; 3] {
    let mut reversed = Vec::new();
    // (The vertex → sample field mapping is checked by hand in
    // `embedding.rs`; the rule is what is written out here.)
    let estimate = walk_by_the_rule(p, rule, |v, target, _| {
        reversed.push(v.training_sample(target));
    });
    out.extend(reversed.iter().rev());
    estimate
}

/// `Ok` if both give the same samples and estimates bit for bit, else where
/// they first differ.
fn compare(
    samples: (&[TrainingSample], &[TrainingSample]),
    estimates: (&[[f32; 3]], &[[f32; 3]]),
) -> Result<(), String> {
    if samples.0.len() != samples.1.len() {
        return Err(format!(
            "{} vs {} samples",
            samples.0.len(),
            samples.1.len()
        ));
    }
    for (i, (a, b)) in samples.0.iter().zip(samples.1).enumerate() {
        if bytemuck::bytes_of(a) != bytemuck::bytes_of(b) {
            return Err(format!("sample {i}: {a:?} vs {b:?}"));
        }
    }
    if nan_bits(estimates.0) != nan_bits(estimates.1) {
        return Err(format!("estimates {:?} vs {:?}", estimates.0, estimates.1));
    }
    Ok(())
}

#[test]
fn batch_recorder_matches_one_path_recorder_per_path() {
    let mut rng = Pcg32::new(2024, 7);
    // One recorder of each kind for every block: storage reused, samples
    // accumulating over blocks.
    let mut batch = BatchRecorder::new();
    let mut single = PathRecorder::new();
    let (mut empty_blocks, mut nan_samples, mut escaped_only) = (0, 0, 0);
    for block in 0..300 {
        let paths = random_block(&mut rng);
        let before = batch.ignored_calls();
        let ignored = record_wavefront(&mut batch, &paths, &mut rng);
        assert_eq!(batch.ignored_calls() - before, ignored, "block {block}");
        let total_hits: usize = paths.iter().map(|p| p.hits.len()).sum();
        assert_eq!(batch.vertex_count(), total_hits);
        let estimates = batch.end().to_vec();
        assert_eq!(batch.paths(), 0);
        assert_eq!(nan_bits(batch.estimates()), nan_bits(&estimates));
        let expected = record_one_by_one(&mut single, &paths);
        assert_eq!(estimates.len(), paths.len());
        if let Err(e) = compare((batch.samples(), single.samples()), (&estimates, &expected)) {
            panic!("block {block} ({} paths): {e}", paths.len());
        }
        empty_blocks += usize::from(paths.is_empty());
        nan_samples += batch
            .samples()
            .iter()
            .filter(|s| s.radiance.iter().any(|x| x.is_nan()))
            .count();
        escaped_only += paths
            .iter()
            .filter(|p| p.hits.is_empty() && !p.escapes.is_empty())
            .count();
        // Now and then hand the samples over, from both.
        if block % 7 == 0 {
            assert_eq!(batch.drain_samples().count(), single.samples().len());
            single.clear_samples();
        }
    }
    // The random blocks did reach the cases they are meant to.
    assert!(empty_blocks > 0, "no empty block");
    assert!(escaped_only > 0, "no camera ray that escaped");
    assert!(nan_samples > 0, "no NaN target");
}

#[test]
fn batch_recorder_matches_the_rule_written_out() {
    let mut rng = Pcg32::new(99, 3);
    let mut batch = BatchRecorder::new();
    for block in 0..200 {
        let paths = random_block(&mut rng);
        record_wavefront(&mut batch, &paths, &mut rng);
        batch.clear_samples();
        let estimates = batch.end().to_vec();
        let mut samples = Vec::new();
        let expected: Vec<_> = paths
            .iter()
            .map(|p| by_the_rule(p, Rule::Documented, &mut samples))
            .collect();
        if let Err(e) = compare((batch.samples(), &samples), (&estimates, &expected)) {
            panic!("block {block}: {e}");
        }
    }
}

/// Negative control: the comparison above is not vacuous. A propagation
/// that differs from the documented one in one place (the emission counted
/// MIS-weighted in the target, or the roulette scale dropped) is flagged on
/// the same random blocks, while the documented one is not.
#[test]
fn the_comparison_flags_a_different_propagation() {
    let mut rng = Pcg32::new(99, 3);
    let mut batch = BatchRecorder::new();
    let mut flagged = [0u32; 3];
    let blocks = 200;
    for _ in 0..blocks {
        let paths = random_block(&mut rng);
        record_wavefront(&mut batch, &paths, &mut rng);
        batch.clear_samples();
        let estimates = batch.end().to_vec();
        for (i, rule) in [Rule::Documented, Rule::MisWeightedTarget, Rule::NoRoulette]
            .into_iter()
            .enumerate()
        {
            let mut samples = Vec::new();
            let expected: Vec<_> = paths
                .iter()
                .map(|p| by_the_rule(p, rule, &mut samples))
                .collect();
            let same = compare((batch.samples(), &samples), (&estimates, &expected)).is_ok();
            flagged[i] += u32::from(!same);
        }
    }
    println!(
        "blocks flagged (documented, MIS-weighted target, no roulette): {flagged:?} of {blocks}"
    );
    assert_eq!(flagged[0], 0, "the documented rule differs");
    // Most blocks of two or more paths have an MIS-weighted emission or a
    // roulette scale somewhere that reaches a target or an estimate.
    assert!(
        flagged[1] > blocks / 2,
        "MIS-weighted target flagged in {} blocks",
        flagged[1]
    );
    assert!(
        flagged[2] > blocks / 2,
        "dropped roulette flagged in {} blocks",
        flagged[2]
    );
}

#[test]
fn batch_recorder_edge_cases() {
    let mut rec = BatchRecorder::new();
    // Nothing started: everything ignored, nothing recorded.
    assert_eq!(rec.paths(), 0);
    assert!(!rec.add_vertex(0, PathVertex::default()));
    assert!(!rec.add_escaped_radiance(0, [1.0; 3], 1.0));
    assert!(rec.end().is_empty());
    assert_eq!(rec.ignored_calls(), 2);
    // Zero paths.
    rec.start(0);
    assert!(!rec.add_direct(0, [1.0; 3]));
    assert!(rec.end().is_empty());
    assert!(rec.is_empty());
    // An unfinished block is discarded by the next start.
    rec.start(2);
    assert!(rec.add_vertex(1, PathVertex::default()));
    rec.start(3);
    assert_eq!(rec.vertex_count(), 0);
    assert!(rec.last_vertex(1).is_none());
    // NaN inputs: no panic; NaN reaches the targets and estimates it feeds
    // and the field rejects those samples.
    let continuation = Continuation {
        wi: [0.0, 0.0, 1.0],
        sample_pdf: 0.5,
        bsdf_cos: [0.25; 3],
        ..Continuation::default()
    };
    for slot in 0..3 {
        assert!(rec.add_vertex(slot, PathVertex::default()));
        assert!(rec.set_continuation(slot, continuation));
    }
    assert!(rec.add_escaped_radiance(0, [f32::NAN, 1.0, 1.0], 1.0));
    assert!(rec.set_continuation(
        1,
        Continuation {
            sample_pdf: f32::NAN,
            ..continuation
        }
    ));
    assert!(rec.add_direct(1, [0.5; 3]));
    assert!(rec.add_escaped_radiance(2, [2.0; 3], 0.5));
    assert_eq!(rec.last_vertex(2).map(|v| v.sample_pdf), Some(0.5));
    let l0 = rec.end().to_vec();
    assert!(l0[0][0].is_nan() && l0[0][1] == 0.5);
    assert_eq!(l0[1], [0.5; 3]); // a NaN pdf ends the path: its NEE only
    assert_eq!(l0[2], [0.5; 3]);
    // Slot 0's and slot 2's samples (slot 1 ended), in slot order.
    assert_eq!(rec.len(), 2);
    assert!(rec.samples()[0].radiance[0].is_nan());
    assert_eq!(rec.samples()[1].radiance, [2.0; 3]);
    // After end the block is gone.
    assert!(!rec.add_direct(0, [1.0; 3]));
    let config = GuidingConfig::npm_radiance().with_size(ModelSize::Small);
    let mut field = GuidingField::new(config, [-1.0; 3], [1.0; 3]).unwrap();
    assert_eq!(rec.flush_into(&mut field), 2);
    assert!(rec.is_empty());
    let stats = field.stats();
    assert_eq!((stats.accepted_samples, stats.rejected_samples[0]), (1, 1));
}

/// The MIS-weighted incident radiance of each sample of a path, written out
/// from the recorder docs: `L̃_i(k) = L̃_o(k + 1)` (the escaped radiance's
/// MIS share for the last vertex), in path order.
fn mis_radiance_by_the_rule(p: &Path) -> Vec<[f32; 3]> {
    let mut reversed = Vec::new();
    walk_by_the_rule(p, Rule::Documented, |_, _, estimate| {
        reversed.push(estimate);
    });
    reversed.reverse();
    reversed
}

/// The bits of `values` with every NaN as the canonical one (a NaN's payload
/// depends on which operand of an operation was NaN).
fn nan_bits(values: &[[f32; 3]]) -> Vec<u32> {
    values
        .iter()
        .flatten()
        .map(|x| {
            if x.is_nan() {
                f32::NAN.to_bits()
            } else {
                x.to_bits()
            }
        })
        .collect()
}

/// Both recorders keep one MIS-weighted incident radiance per sample, equal
/// bit for bit to the rule written out; it differs from the training
/// radiance wherever the emission found along `wi` had an MIS weight below
/// one (checked to happen), and draining or clearing keeps it in step.
#[test]
fn mis_radiance_follows_the_rule_and_the_samples() {
    let mut rng = Pcg32::new(4242, 5);
    let mut batch = BatchRecorder::new();
    let mut single = PathRecorder::new();
    let mut differs = 0usize;
    for block in 0..200 {
        let paths = random_block(&mut rng);
        record_wavefront(&mut batch, &paths, &mut rng);
        batch.end();
        record_one_by_one(&mut single, &paths);
        let expected: Vec<[f32; 3]> = paths.iter().flat_map(mis_radiance_by_the_rule).collect();
        assert_eq!(
            batch.mis_radiance().len(),
            batch.samples().len(),
            "block {block}"
        );
        assert_eq!(
            nan_bits(batch.mis_radiance()),
            nan_bits(&expected),
            "block {block}"
        );
        assert_eq!(
            nan_bits(single.mis_radiance()),
            nan_bits(&expected),
            "block {block}"
        );
        differs += batch
            .samples()
            .iter()
            .zip(batch.mis_radiance())
            .filter(|(s, m)| {
                s.radiance
                    .iter()
                    .zip(m.iter())
                    .any(|(a, b)| a.to_bits() != b.to_bits())
            })
            .count();
        if block % 2 == 0 {
            let (mut s, mut m) = (Vec::new(), Vec::new());
            batch.drain_into(&mut s, &mut m);
            assert_eq!(s.len(), m.len());
            assert!(batch.samples().is_empty() && batch.mis_radiance().is_empty());
        } else {
            let _ = batch.drain_samples().count();
            assert!(batch.mis_radiance().is_empty());
        }
        single.clear_samples();
        assert!(single.mis_radiance().is_empty());
    }
    assert!(
        differs > 0,
        "no sample whose emission had an MIS weight below one"
    );
}

/// Reflected radiance (`keep_reflected`), written out on one path of three vertices: vertex 1
/// (`L̃_r = D₁ + β₁ L̃_i(1)` with `L̃_i(1)` = vertex 2's emission, MIS-weighted, plus its
/// direct light) and vertex 0 (`D₀ + β₀ (w₁ L_e(1) + L̃_r(1))`); vertex 2 ended and keeps
/// none. Both recorders agree; nothing is kept unless asked for.
#[test]
fn reflected_radiance_written_out() {
    let v0 = PathVertex {
        position: [0.0, 0.0, 0.0],
        normal: [0.0, 0.0, 1.0],
        direct: [0.1; 3],
        wi: [0.0, 0.0, 1.0],
        sample_pdf: 0.5,
        bsdf_cos: [0.25; 3],
        ..PathVertex::default()
    };
    // A delta vertex after a roulette survival (scale 2): reflected radiance all the same.
    let mut v1 = PathVertex::default();
    (v1.position, v1.normal, v1.wi) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]);
    (v1.emitted, v1.emitted_mis_weight, v1.direct) = ([2.0; 3], 0.5, [0.2; 3]);
    (v1.sample_pdf, v1.bsdf_cos, v1.continuation_scale) = (1.0, [0.5; 3], 2.0);
    v1.is_delta = true;
    let mut v2 = PathVertex::default();
    (v2.position, v2.emitted, v2.direct) = ([2.0, 0.0, 0.0], [4.0; 3], [0.3; 3]);
    v2.emitted_mis_weight = 0.25;
    // Vertex 2 ended: its light towards 1 is w₂ L_e + D₂ = 1 + 0.3.
    let r1 = 0.2 + 0.5 * 2.0 / 1.0 * (0.25 * 4.0 + 0.3);
    let r0 = 0.1 + 0.25 / 0.5 * (0.5 * 2.0 + r1);
    let expect = [
        ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], r1),
        ([0.0; 3], [0.0, 0.0, 1.0], r0),
    ];

    let mut one = PathRecorder::new();
    let mut batch = BatchRecorder::new();
    for keep in [false, true] {
        one.keep_reflected(keep);
        batch.keep_reflected(keep);
        one.start_path();
        batch.start(1);
        for v in [v0, v1, v2] {
            one.add_vertex(v);
            batch.add_vertex(0, v);
        }
        one.end_path();
        batch.end();
        let mut got = Vec::new();
        one.drain_reflected_into(&mut got);
        if !keep {
            assert!(got.is_empty() && batch.reflected().is_empty());
            continue;
        }
        assert_eq!(got, batch.reflected());
        assert_eq!(got.len(), 2, "{got:?}");
        for (g, (p, n, r)) in got.iter().zip(expect) {
            assert_eq!((g.position, g.normal), (p, n));
            assert!(
                g.radiance.iter().all(|x| (x - r).abs() < 1e-6),
                "{g:?} vs {r}"
            );
        }
        let mut drained = Vec::new();
        batch.drain_reflected_into(&mut drained);
        assert_eq!(drained.len(), 2);
        assert!(batch.reflected().is_empty());
    }
}
