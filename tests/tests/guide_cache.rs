//! The guide cache (`guiding::GuideCache`): a lookup that lands in a cell
//! is the network's decode at the cell's decode point bit for bit (NPM,
//! NASG, DF), stale caches are refused and `refresh` equals a fresh build,
//! `extend` does not depend on the order of the positions and ignores
//! positions off the grid, misses are decoded by the network, and the
//! stochastic lookup picks the neighbouring cells with the tent
//! (trilinear) weights: a chi² test over the cells a lane came from, with a
//! committed negative control showing the same test rejects a defective
//! lookup and wrong rules.

use guiding::{
    CacheLookup, CacheOptions, DirectionSample, DistributionBatch, FieldConfig, GuideCache,
    GuidingConfig, GuidingError, GuidingField, ModelSize, PathRecorder, PathVertex, QueryPoint,
    Target,
};
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::math::INV_FOUR_PI;
use guiding_core::sphere::square_to_uniform_sphere;
use guiding_tests::chi2::sidak;
use guiding_tests::rng::Pcg32;
use statrs::distribution::{ChiSquared, ContinuousCDF};
use std::collections::HashSet;

const LO: [f32; 3] = [-1.0, -2.0, 0.0];
const HI: [f32; 3] = [1.0, 2.0, 3.0];
/// Cells on the longest axis (4 long): cells of side 0.5, so cell centres
/// and the positions between them below are exact in `f32`.
const RES: u32 = 8;
const OPTIONS: CacheOptions = CacheOptions { resolution: RES };

fn training() -> FieldConfig {
    FieldConfig::DEFAULT
        .with_batch_size(512)
        .with_steps_per_update(4)
        .with_threads(2)
}

/// The radiance-target presets (the only ones a cache accepts), small.
fn radiance_presets() -> Vec<(&'static str, GuidingConfig)> {
    [
        ("npm", GuidingConfig::npm_radiance()),
        ("nasg", GuidingConfig::nasg()),
        ("df-n", GuidingConfig::df_nearest()),
        ("df-l", GuidingConfig::df_linear()),
    ]
    .into_iter()
    .map(|(n, c)| {
        assert_eq!(c.target, Target::Radiance);
        (n, c.with_size(ModelSize::Small).with_training(training()))
    })
    .collect()
}

fn in_box(rng: &mut Pcg32) -> Vec3 {
    Vec3::new(
        rng.uniform(LO[0], HI[0]),
        rng.uniform(LO[1], HI[1]),
        rng.uniform(LO[2], HI[2]),
    )
}

fn unit(rng: &mut Pcg32) -> Vec3 {
    square_to_uniform_sphere(rng.next_vec2())
}

/// Radiance 10 from a cone (cos > 0.9) towards a point light, 0.1 elsewhere:
/// the learned distribution depends on the position.
fn radiance(p: Vec3, dir: Vec3) -> f32 {
    let to_light = (Vec3::new(0.3, 1.5, 2.5) - p).normalize();
    if dir.dot(to_light) > 0.9 {
        10.0
    } else {
        0.1
    }
}

/// One-vertex paths at random positions, uniformly sampled directions.
fn record(rec: &mut PathRecorder, rng: &mut Pcg32, n: usize) {
    for _ in 0..n {
        let p = in_box(rng);
        let wi = unit(rng);
        rec.start_path();
        rec.add_vertex(PathVertex {
            position: p.to_array(),
            normal: unit(rng).to_array(),
            wo: unit(rng).to_array(),
            roughness: 1.0,
            wi: wi.to_array(),
            sample_pdf: INV_FOUR_PI,
            bsdf_pdf: INV_FOUR_PI,
            bsdf_cos: [1.0; 3],
            ..PathVertex::default()
        });
        rec.add_escaped_radiance([radiance(p, wi); 3], 1.0);
        rec.end_path();
    }
}

/// Trains once more on fresh paths; the generation must change.
fn train_once(field: &mut GuidingField, rng: &mut Pcg32) {
    let before = field.generation();
    let mut rec = PathRecorder::new();
    record(&mut rec, rng, 600);
    field.add_samples(rec.samples());
    let report = field.update();
    assert!(report.steps > 0, "{report:?}");
    assert_ne!(field.generation(), before);
}

fn trained(config: GuidingConfig, seed: u64) -> GuidingField {
    let mut field = GuidingField::new(config, LO, HI).unwrap();
    let mut rng = Pcg32::new(seed, 3);
    for _ in 0..3 {
        train_once(&mut field, &mut rng);
    }
    field
}

/// A radiance query at `p` (normal, `ωo` and roughness arbitrary: a
/// radiance guide ignores them).
fn query(p: Vec3, rng: &mut Pcg32) -> QueryPoint {
    QueryPoint::from_vec3(p, unit(rng), unit(rng), rng.next_f32())
}

/// The lower corner of the cache's grid and its cell side, as
/// `build_cache` documents them: the field's box less one cell, cells of
/// side `max extent / resolution`.
fn grid_origin(cache: &GuideCache) -> (Vec3, f32) {
    let h = cache.cell_size();
    (Vec3::from_array(LO) - Vec3::splat(h), h)
}

/// The integer cell of `p` (`None` off the grid), computed independently.
fn cell_of(cache: &GuideCache, p: Vec3) -> Option<[u32; 3]> {
    let (lo, h) = grid_origin(cache);
    let c = (p - lo) / h;
    let res = cache.resolution();
    let mut out = [0; 3];
    for a in 0..3 {
        if !(c[a].is_finite() && c[a] >= 0.0 && (c[a] as u32) < res[a]) {
            return None;
        }
        out[a] = c[a] as u32;
    }
    Some(out)
}

fn cell_centre(cache: &GuideCache, cell: [u32; 3]) -> Vec3 {
    let (lo, h) = grid_origin(cache);
    lo + (Vec3::new(cell[0] as f32, cell[1] as f32, cell[2] as f32) + 0.5) * h
}

/// Fixed directions and random pairs at which lanes are compared.
fn probes() -> (Vec<Vec3>, Vec<Vec2>) {
    let mut rng = Pcg32::new(77, 5);
    let dirs = (0..4).map(|_| unit(&mut rng)).collect();
    let us = (0..4).map(|_| rng.next_vec2()).collect();
    (dirs, us)
}

/// Per lane: the bits of the pdfs at the probe directions, of the samples
/// at the probe random pairs (direction and pdf) and of the selection
/// probability.
fn fingerprints(field: &GuidingField, batch: &DistributionBatch) -> Vec<Vec<u32>> {
    let (dirs, us) = probes();
    let n = batch.len();
    let (mut lanes, mut d, mut u) = (Vec::new(), Vec::new(), Vec::new());
    for l in 0..n as u32 {
        for k in 0..dirs.len() {
            lanes.push(l);
            d.push(dirs[k]);
            u.push(us[k]);
        }
    }
    let mut pdf = vec![0.0; lanes.len()];
    field.pdf_decoded(batch, &lanes, &d, &mut pdf).unwrap();
    let zero = DirectionSample {
        direction: Vec3::ZERO,
        pdf: 0.0,
    };
    let mut samples = vec![zero; lanes.len()];
    field
        .sample_decoded(batch, &lanes, &u, &mut samples)
        .unwrap();
    let m = dirs.len();
    (0..n)
        .map(|l| {
            let mut f = vec![batch.selection_probability(l).to_bits()];
            for k in l * m..(l + 1) * m {
                f.push(pdf[k].to_bits());
                let s = samples[k];
                f.extend(s.direction.to_array().map(f32::to_bits));
                f.push(s.pdf.to_bits());
            }
            f
        })
        .collect()
}

/// Fingerprints of the cache's lanes for `queries` with `jitter`.
fn cached(
    cache: &GuideCache,
    field: &GuidingField,
    queries: &[QueryPoint],
    jitter: &[Vec3],
) -> (Vec<Vec<u32>>, CacheLookup, Vec<u32>) {
    let mut batch = DistributionBatch::new();
    let mut missed = Vec::new();
    let lookup = cache
        .decode_batch(field, queries, jitter, &mut batch, &mut missed)
        .unwrap();
    assert_eq!(batch.len(), queries.len());
    (fingerprints(field, &batch), lookup, missed)
}

/// Fingerprints of the network's decode of `queries`.
fn network(field: &GuidingField, queries: &[QueryPoint]) -> Vec<Vec<u32>> {
    let mut batch = DistributionBatch::new();
    field.decode_batch(queries, &mut batch);
    fingerprints(field, &batch)
}

/// One random position in each of a scattered set of cells (the only
/// position of its cell), inside the field's box.
fn one_position_per_cell(cache_res: [u32; 3], rng: &mut Pcg32) -> Vec<Vec3> {
    let mut out = Vec::new();
    let h = 4.0 / RES as f32;
    let lo = Vec3::from_array(LO) - Vec3::splat(h);
    for z in 1..cache_res[2] - 1 {
        for y in 1..cache_res[1] - 1 {
            for x in 1..cache_res[0] - 1 {
                if (x + 2 * y + 3 * z) % 5 != 0 {
                    continue;
                }
                let c = Vec3::new(x as f32, y as f32, z as f32);
                let f = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
                out.push(lo + (c + f * 0.98 + 0.01) * h);
            }
        }
    }
    out
}

#[test]
fn a_lookup_at_the_only_position_of_its_cell_is_the_network_decode_bit_for_bit() {
    for (i, (name, config)) in radiance_presets().into_iter().enumerate() {
        let field = trained(config, 10 + i as u64);
        let mut rng = Pcg32::new(20 + i as u64, 1);
        let empty = field.build_cache(&[], &OPTIONS).unwrap();
        assert_eq!(empty.cells(), 0);
        let positions = one_position_per_cell(empty.resolution(), &mut rng);
        let cache = field.build_cache(&positions, &OPTIONS).unwrap();
        assert_eq!(cache.cells(), positions.len(), "{name}");
        assert_eq!(cache.generation(), field.generation());
        // In another order than the cache's cells, with other normals / ωo.
        let mut queries: Vec<QueryPoint> = positions.iter().map(|&p| query(p, &mut rng)).collect();
        queries.reverse();
        let jitter = vec![Vec3::splat(0.5); queries.len()];
        let (got, lookup, missed) = cached(&cache, &field, &queries, &jitter);
        assert_eq!(
            lookup,
            CacheLookup {
                hits: queries.len() as u64,
                misses: 0
            }
        );
        assert!(missed.is_empty());
        let want = network(&field, &queries);
        for (k, (g, w)) in got.iter().zip(&want).enumerate() {
            assert_eq!(g, w, "{name}: query {k} at {:?}", queries[k].position);
        }
        // The lanes differ from cell to cell (the comparison has teeth).
        let distinct: HashSet<&Vec<u32>> = got.iter().collect();
        assert!(distinct.len() > got.len() / 2, "{name}: {}", distinct.len());
    }
}

#[test]
fn build_cache_refuses_product_targets_and_bad_resolutions() {
    let products = [
        GuidingConfig::npm_product(),
        GuidingConfig::nasg_product(),
        GuidingConfig::df_linear().with_target(Target::Product),
    ];
    let p = [Vec3::new(0.0, 0.0, 1.0)];
    for config in products {
        let field = GuidingField::new(config.with_size(ModelSize::Small), LO, HI).unwrap();
        assert!(
            matches!(
                field.build_cache(&p, &OPTIONS),
                Err(GuidingError::InvalidConfig(_))
            ),
            "{config:?}"
        );
    }
    let field = GuidingField::new(radiance_presets()[0].1, LO, HI).unwrap();
    for resolution in [0, 257, u32::MAX] {
        let options = CacheOptions { resolution };
        assert!(
            matches!(
                field.build_cache(&p, &options),
                Err(GuidingError::InvalidConfig(_))
            ),
            "resolution {resolution}"
        );
    }
    for (resolution, res) in [(1, [3, 3, 3]), (256, [130, 258, 194])] {
        let options = CacheOptions { resolution };
        let cache = field.build_cache(&p, &options).unwrap();
        assert_eq!(cache.resolution(), res, "resolution {resolution}");
        assert_eq!(cache.cell_size(), 4.0 / resolution as f32);
        assert_eq!(cache.cells(), 1);
    }
}

#[test]
fn a_stale_cache_is_refused_and_refresh_equals_a_fresh_build() {
    for (i, (name, config)) in radiance_presets().into_iter().enumerate() {
        let mut field = trained(config, 30 + i as u64);
        let other = trained(config, 40 + i as u64);
        let mut rng = Pcg32::new(50 + i as u64, 1);
        // Many positions per cell: the decode points are centroids.
        let positions: Vec<Vec3> = (0..3000).map(|_| in_box(&mut rng)).collect();
        let mut cache = field.build_cache(&positions, &OPTIONS).unwrap();
        let queries: Vec<QueryPoint> = (0..200)
            .map(|_| {
                let p = in_box(&mut rng);
                query(p, &mut rng)
            })
            .collect();
        let jitter: Vec<Vec3> = (0..queries.len())
            .map(|_| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()))
            .collect();
        let before = cached(&cache, &field, &queries, &jitter).0;
        let g0 = cache.generation();

        let stale = |cache: &GuideCache, field: &GuidingField| {
            let mut batch = DistributionBatch::new();
            field.decode_batch(&queries[..3], &mut batch);
            let mut missed = vec![7];
            let r = cache.decode_batch(field, &queries, &jitter, &mut batch, &mut missed);
            assert!(
                matches!(r, Err(GuidingError::StaleDistribution { .. })),
                "{name}: {r:?}"
            );
            assert!(batch.is_empty() && missed.is_empty(), "{name}");
        };
        // Another field.
        stale(&cache, &other);
        assert!(matches!(
            cache.clone().refresh(&other),
            Err(GuidingError::StaleDistribution { .. })
        ));
        assert!(matches!(
            cache.clone().extend(&other, &positions),
            Err(GuidingError::StaleDistribution { .. })
        ));

        train_once(&mut field, &mut rng);
        stale(&cache, &field);
        assert!(matches!(
            cache.clone().extend(&field, &positions),
            Err(GuidingError::StaleDistribution { .. })
        ));
        assert_eq!(cache.generation(), g0);

        let cells = cache.cells();
        cache.refresh(&field).unwrap();
        assert_eq!(cache.generation(), field.generation());
        assert_eq!(cache.cells(), cells);
        let refreshed = cached(&cache, &field, &queries, &jitter);
        let fresh = field.build_cache(&positions, &OPTIONS).unwrap();
        assert_eq!(fresh.cells(), cells);
        let rebuilt = cached(&fresh, &field, &queries, &jitter);
        assert_eq!(refreshed.1, rebuilt.1, "{name}");
        assert_eq!(refreshed.2, rebuilt.2, "{name}");
        for (k, (a, b)) in refreshed.0.iter().zip(&rebuilt.0).enumerate() {
            assert_eq!(a, b, "{name}: query {k}");
        }
        // The update changed the distributions (so the equality above says
        // something), and a second refresh at the same generation is a no-op.
        assert_ne!(before, refreshed.0, "{name}");
        cache.refresh(&field).unwrap();
        assert_eq!(cached(&cache, &field, &queries, &jitter).0, refreshed.0);
    }
}

#[test]
fn extend_is_order_independent_counts_new_cells_and_ignores_bad_positions() {
    let invalid = [
        Vec3::splat(f32::NAN),
        Vec3::new(0.0, f32::NAN, 1.0),
        Vec3::new(f32::INFINITY, 0.0, 1.0),
        Vec3::new(0.0, f32::NEG_INFINITY, 1.0),
        Vec3::new(100.0, 0.0, 1.0),
        Vec3::new(0.0, -100.0, 1.0),
        Vec3::new(0.0, 0.0, 1e30),
        Vec3::splat(-1e30),
        Vec3::new(HI[0] + 2.0, 0.0, 1.0),
        Vec3::new(LO[0] - 2.0, 0.0, 1.0),
    ];
    for (i, (name, config)) in radiance_presets().into_iter().enumerate() {
        let field = trained(config, 60 + i as u64);
        let mut rng = Pcg32::new(70 + i as u64, 1);
        // Positions in the lower half of the box (z < 1.5), a few just
        // outside its faces (inside the grid's one-cell margin), repeated
        // positions and the invalid ones mixed in.
        let mut positions: Vec<Vec3> = (0..1500)
            .map(|_| {
                let p = in_box(&mut rng);
                Vec3::new(p.x * 1.1, p.y * 1.05, p.z * 0.5 - 0.1)
            })
            .collect();
        let repeats: Vec<Vec3> = positions[..100].to_vec();
        positions.extend(repeats);
        positions.extend(invalid);
        let distinct = |ps: &[Vec3], cache: &GuideCache| -> HashSet<[u32; 3]> {
            ps.iter().filter_map(|&p| cell_of(cache, p)).collect()
        };

        let mut a = field.build_cache(&[], &OPTIONS).unwrap();
        let want_cells = distinct(&positions, &a);
        assert_eq!(a.extend(&field, &positions).unwrap(), want_cells.len());
        assert_eq!(a.cells(), want_cells.len(), "{name}");
        assert_eq!(a.extend(&field, &positions).unwrap(), 0);

        // Shuffled (Fisher–Yates): the same cells and decode points.
        let mut shuffled = positions.clone();
        for k in (1..shuffled.len()).rev() {
            let j = rng.next_u32() as usize % (k + 1);
            shuffled.swap(k, j);
        }
        let b = field.build_cache(&shuffled, &OPTIONS).unwrap();
        assert_eq!(b.cells(), a.cells());
        let queries: Vec<QueryPoint> = (0..400)
            .map(|_| {
                let p = in_box(&mut rng);
                query(Vec3::new(p.x, p.y, p.z * 0.5), &mut rng)
            })
            .collect();
        let jitter: Vec<Vec3> = (0..queries.len())
            .map(|_| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()))
            .collect();
        let (fa, la, ma) = cached(&a, &field, &queries, &jitter);
        let (fb, lb, mb) = cached(&b, &field, &queries, &jitter);
        assert_eq!((la, &ma), (lb, &mb), "{name}");
        assert_eq!(
            la.misses, 0,
            "{name}: every query is inside an occupied cell"
        );
        for (k, (x, y)) in fa.iter().zip(&fb).enumerate() {
            assert_eq!(x, y, "{name}: query {k}");
        }

        // Invalid positions alone add nothing.
        let cells = a.cells();
        assert_eq!(a.extend(&field, &invalid).unwrap(), 0, "{name}");
        assert_eq!(a.cells(), cells);

        // New positions overlapping the occupied half: as many cells as new
        // distinct cells among them.
        let upper: Vec<Vec3> = (0..300)
            .map(|_| {
                let p = in_box(&mut rng);
                Vec3::new(p.x, p.y, 1.0 + p.z * 0.5)
            })
            .collect();
        let old = distinct(&positions, &a);
        let new = distinct(&upper, &a);
        let added = new.difference(&old).count();
        assert!(added > 0 && added < new.len(), "{name}: {added}");
        assert_eq!(a.extend(&field, &upper).unwrap(), added, "{name}");
        assert_eq!(a.cells(), cells + added);

        // Misses: invalid query positions and one in the box but with no
        // occupied cell near (the cache `b` holds the lower half only),
        // between hits; they are the network's decode of the query.
        let mut mixed: Vec<QueryPoint> = Vec::new();
        let mut want_missed = Vec::new();
        let far = [Vec3::new(0.0, 0.0, 2.9), Vec3::new(-0.9, 1.9, 2.8)];
        for (k, &p) in invalid.iter().chain(&far).enumerate() {
            mixed.push(queries[k]);
            want_missed.push(mixed.len() as u32);
            mixed.push(query(p, &mut rng));
        }
        let jitter: Vec<Vec3> = (0..mixed.len())
            .map(|_| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()))
            .collect();
        let (got, lookup, missed) = cached(&b, &field, &mixed, &jitter);
        assert_eq!(missed, want_missed, "{name}");
        assert_eq!(
            lookup,
            CacheLookup {
                hits: (mixed.len() - want_missed.len()) as u64,
                misses: want_missed.len() as u64
            },
            "{name}"
        );
        for &m in &missed {
            let q = mixed[m as usize];
            let want = network(&field, std::slice::from_ref(&q));
            assert_eq!(got[m as usize], want[0], "{name}: miss at {:?}", q.position);
        }
    }
}

// ---------------------------------------------------------------------------
// The stochastic trilinear lookup.

/// Lanes drawn per query position.
const LOOKUPS: usize = 16_384;
/// Family-wise significance of the lookup test (Šidák over its positions).
const LOOKUP_ALPHA: f64 = 0.01;
/// Cells expecting fewer lanes than this are pooled.
const MIN_EXPECTED: f64 = 5.0;

/// Query positions of the lookup test, as `(cell below on every axis, t)`:
/// the position is that cell's centre plus `t` cells, so its tent weights
/// are `1 − t` (the cell below) and `t` (the cell above) per axis. The last
/// one has four neighbours expecting 4 lanes each (pooled).
fn lookup_positions() -> Vec<([u32; 3], [f32; 3])> {
    vec![
        ([2, 3, 2], [0.25, 0.625, 0.125]),
        ([1, 6, 4], [0.875, 0.375, 0.5]),
        ([3, 4, 3], [0.5, 0.5, 1.0 / 1024.0]),
    ]
}

/// The eight neighbours of a position in corner order (bit `a` of the index
/// set: the cell above on axis `a`).
fn corners(base: [u32; 3]) -> [[u32; 3]; 8] {
    std::array::from_fn(|c| std::array::from_fn(|a| base[a] + ((c >> a) & 1) as u32))
}

/// The categories a lane is counted in: the eight neighbours, then any
/// other cell (probability 0 under every rule: a lane there rejects).
const CATEGORIES: usize = 9;

/// Per-category probabilities of a rule that picks, on every axis
/// independently, the cell above with probability `up[a]`.
fn corner_weights(up: [f64; 3]) -> [f64; CATEGORIES] {
    std::array::from_fn(|c| {
        if c == 8 {
            return 0.0;
        }
        (0..3)
            .map(|a| {
                if (c >> a) & 1 == 1 {
                    up[a]
                } else {
                    1.0 - up[a]
                }
            })
            .product()
    })
}

/// The tent weights (what the lookup must follow).
fn tent(t: [f32; 3]) -> [f64; CATEGORIES] {
    corner_weights(t.map(f64::from))
}

/// Pearson's chi² of `observed` against `probabilities · n`, cells
/// expecting fewer than [`MIN_EXPECTED`] pooled (into the smallest kept
/// cell when the pool itself expects too few), as `tests/src/chi2.rs` does.
/// Lanes in a cell of probability 0 reject outright (statistic ∞, p 0).
#[derive(Clone, Copy, Debug)]
struct Pearson {
    statistic: f64,
    dof: usize,
    pooled: usize,
    p: f64,
}

fn pearson(observed: &[u64; CATEGORIES], probabilities: &[f64; CATEGORIES]) -> Pearson {
    let n = observed.iter().sum::<u64>() as f64;
    if observed
        .iter()
        .zip(probabilities)
        .any(|(&o, &w)| o > 0 && w <= 0.0)
    {
        return Pearson {
            statistic: f64::INFINITY,
            dof: 0,
            pooled: 0,
            p: 0.0,
        };
    }
    let mut cells: Vec<(f64, f64)> = probabilities
        .iter()
        .zip(observed)
        .filter(|(&w, _)| w > 0.0)
        .map(|(&w, &o)| (w * n, o as f64))
        .collect();
    cells.sort_by(|a, b| a.0.total_cmp(&b.0));
    let low = cells.partition_point(|c| c.0 < MIN_EXPECTED);
    let pool = cells[..low]
        .iter()
        .fold((0.0, 0.0), |s, c| (s.0 + c.0, s.1 + c.1));
    let mut kept = cells[low..].to_vec();
    if low > 0 {
        if pool.0 < MIN_EXPECTED && !kept.is_empty() {
            kept[0].0 += pool.0;
            kept[0].1 += pool.1;
        } else {
            kept.push(pool);
        }
    }
    let statistic: f64 = kept.iter().map(|(e, o)| (o - e) * (o - e) / e).sum();
    let dof = kept.len().saturating_sub(1);
    let p = if dof == 0 {
        // One cell holds everything: nothing to test, nothing rejected.
        1.0
    } else {
        ChiSquared::new(dof as f64).unwrap().sf(statistic)
    };
    Pearson {
        statistic,
        dof,
        pooled: low,
        p,
    }
}

/// The NPM field and a cache with one decode point per cell, at every cell
/// centre of the grid.
fn lookup_setup() -> (GuidingField, GuideCache) {
    let field = trained(radiance_presets()[0].1, 90);
    let empty = field.build_cache(&[], &OPTIONS).unwrap();
    let res = empty.resolution();
    let mut centres = Vec::new();
    for z in 0..res[2] {
        for y in 0..res[1] {
            for x in 0..res[0] {
                centres.push(cell_centre(&empty, [x, y, z]));
            }
        }
    }
    let cache = field.build_cache(&centres, &OPTIONS).unwrap();
    assert_eq!(cache.cells(), centres.len());
    assert_eq!(cache.cell_size(), 0.5);
    (field, cache)
}

/// How many of [`LOOKUPS`] lanes at the position `(base, t)` came from each
/// of its eight neighbours (the last count: from any other cell), the
/// jitters `ξ` uniform (seeded) and passed to the cache as `distort(ξ)`. A
/// lane is identified by its fingerprint (the neighbours' fingerprints are
/// distinct).
fn lookup_counts(
    field: &GuidingField,
    cache: &GuideCache,
    base: [u32; 3],
    t: [f32; 3],
    seed: u64,
    distort: impl Fn(Vec3) -> Vec3,
) -> [u64; CATEGORIES] {
    let cells = corners(base);
    let mut rng = Pcg32::new(seed, 11);
    let centres: Vec<QueryPoint> = cells
        .iter()
        .map(|&c| query(cell_centre(cache, c), &mut rng))
        .collect();
    let (known, _, _) = cached(cache, field, &centres, &[Vec3::splat(0.5); 8]);
    assert_eq!(
        known.iter().collect::<HashSet<_>>().len(),
        8,
        "two neighbours of {base:?} decode alike: lanes cannot be told apart"
    );
    let h = cache.cell_size();
    // Exact: `t` is a multiple of 2⁻¹⁰ and the centres of 2⁻².
    let p = cell_centre(cache, base) + Vec3::from_array(t) * h;
    let q = query(p, &mut rng);
    let queries = vec![q; LOOKUPS];
    let jitter: Vec<Vec3> = (0..LOOKUPS)
        .map(|_| distort(Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32())))
        .collect();
    let (lanes, lookup, _) = cached(cache, field, &queries, &jitter);
    assert_eq!(lookup.hits, LOOKUPS as u64);
    let mut counts = [0u64; CATEGORIES];
    for lane in &lanes {
        counts[known.iter().position(|f| f == lane).unwrap_or(8)] += 1;
    }
    counts
}

/// The verdict of the lookup test: per position the chi² against
/// `rule(t)`, rejected if any `p` is below the Šidák-corrected level.
fn lookup_test(
    observed: &[[u64; CATEGORIES]],
    rule: impl Fn([f32; 3]) -> [f64; CATEGORIES],
    label: &str,
) -> bool {
    let positions = lookup_positions();
    let level = sidak(LOOKUP_ALPHA, positions.len());
    let mut rejected = false;
    for ((base, t), obs) in positions.iter().zip(observed) {
        let r = pearson(obs, &rule(*t));
        eprintln!(
            "{label}: cell {base:?} + {t:?}: observed {obs:?}, chi2 {:.2}, dof {} ({} pooled), \
             p {:.3e}, level {level:.3e}",
            r.statistic, r.dof, r.pooled, r.p
        );
        rejected |= r.p < level;
    }
    rejected
}

fn observed_lookups(
    field: &GuidingField,
    cache: &GuideCache,
    distort: impl Fn(Vec3) -> Vec3 + Copy,
) -> Vec<[u64; CATEGORIES]> {
    lookup_positions()
        .into_iter()
        .enumerate()
        .map(|(i, (base, t))| lookup_counts(field, cache, base, t, 1000 + i as u64, distort))
        .collect()
}

#[test]
fn stochastic_lookup_follows_the_tent_weights() {
    let (field, cache) = lookup_setup();
    let observed = observed_lookups(&field, &cache, |xi| xi);
    for o in &observed {
        assert_eq!(o[8], 0, "lanes from a cell that is no neighbour: {o:?}");
    }
    assert!(
        !lookup_test(&observed, tent, "tent"),
        "the lookup's cell frequencies do not follow the trilinear weights"
    );
}

/// Negative control of [`stochastic_lookup_follows_the_tent_weights`], at
/// its level: the same chi² test rejects (a) a defective lookup (simulated
/// through the jitters passed to the cache: a box of half a cell, `x +
/// (ξ − ½)·h/2`, and an uncentred one, `x + ξ·h`) against the tent weights,
/// and (b) wrong rules for the honest lookup's counts: the nearest cell
/// always, and the tent weights with `t` and `1 − t` swapped.
#[test]
fn stochastic_lookup_test_rejects_wrong_rules() {
    let (field, cache) = lookup_setup();
    let half_box = observed_lookups(&field, &cache, |xi| (xi - 0.5) * 0.5 + 0.5);
    assert!(
        lookup_test(&half_box, tent, "defect: half-cell jitter"),
        "a half-cell jitter box passed the tent test"
    );
    let uncentred = observed_lookups(&field, &cache, |xi| xi + 0.5);
    assert!(
        lookup_test(&uncentred, tent, "defect: uncentred jitter"),
        "an uncentred jitter passed the tent test"
    );
    let honest = observed_lookups(&field, &cache, |xi| xi);
    let nearest = |t: [f32; 3]| corner_weights(t.map(|t| f64::from(u8::from(t > 0.5))));
    assert!(
        lookup_test(&honest, nearest, "wrong rule: nearest cell"),
        "the nearest-cell rule was not rejected"
    );
    let swapped = |t: [f32; 3]| corner_weights(t.map(|t| 1.0 - f64::from(t)));
    assert!(
        lookup_test(&honest, swapped, "wrong rule: swapped weights"),
        "swapped tent weights were not rejected"
    );
}
