//! The guide cache (`guiding::GuideCache`): a lookup that lands in a cell
//! is the network's decode at the cell's decode point bit for bit (NPM,
//! NASG, DF), stale caches are refused and `refresh` equals a fresh build,
//! `extend` does not depend on the order of the points and ignores
//! positions off the grid, misses are decoded by the network, and the
//! stochastic lookup picks the neighbouring cells with the tent
//! (trilinear) weights: a chi² test over the cells a lane came from, with a
//! committed negative control showing the same test rejects a defective
//! lookup and wrong rules.
//!
//! The cosine-product mode (`CacheOptions::cosine_product`, NPM only): a
//! lane per (cell, octahedral normal bin) holding the decode at the
//! centroid times the clamped cosine of the normalised mean normal, bit for
//! bit; a query takes its own bin's lane; misses are the network decode
//! times the query's own cosine; `extend` stays order independent and
//! counts lanes; NASG and DF ignore the option. The per-cell selection fit
//! (`GuideCache::fit_selection`) is the argmin of the second-moment
//! estimator written out here independently.

use guiding::{
    CacheLookup, CacheOptions, DirectionSample, DistributionBatch, FieldConfig, GuideCache,
    GuidingConfig, GuidingError, GuidingField, ModelSize, PathRecorder, QueryPoint, SelectionFit,
    Target, TrainingSample,
};
use guiding_core::frame::normalize_or;
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::math::INV_FOUR_PI;
use guiding_core::sphere::square_to_uniform_sphere;
use guiding_tests::chi2::{pearson_statistic, pool_low_cells, sidak};
use guiding_tests::record_uniform_vertex;
use guiding_tests::rng::Pcg32;
use statrs::distribution::{ChiSquared, ContinuousCDF};
use std::collections::HashSet;

const LO: [f32; 3] = [-1.0, -2.0, 0.0];
const HI: [f32; 3] = [1.0, 2.0, 3.0];
/// Cells on the longest axis (4 long): cells of side 0.5, so cell centres
/// and the positions between them below are exact in `f32`.
const RES: u32 = 8;
const OPTIONS: CacheOptions = CacheOptions {
    resolution: RES,
    cosine_product: false,
    df_table: false,
};
/// [`OPTIONS`] with the cosine product per normal bin.
const PRODUCT: CacheOptions = CacheOptions {
    resolution: RES,
    cosine_product: true,
    df_table: false,
};

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
        let (normal, wo) = (unit(rng).to_array(), unit(rng).to_array());
        record_uniform_vertex(rec, (p.to_array(), normal, wo), wi, radiance(p, wi));
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
/// radiance guide ignores them, and so does a cache without the product).
fn query(p: Vec3, rng: &mut Pcg32) -> QueryPoint {
    QueryPoint::from_vec3(p, unit(rng), unit(rng), rng.next_f32())
}

/// Queries at `positions` ([`query`]).
fn queries_at(positions: &[Vec3], rng: &mut Pcg32) -> Vec<QueryPoint> {
    positions.iter().map(|&p| query(p, rng)).collect()
}

/// A unit normal near one of six fixed directions, one per octant pair
/// (the centres of octahedral bins, see [`octahedral_bin`], tilted by up to
/// 0.08 rad): the shading normals of a box-like scene, so a cell's normals
/// share a few bins and a bin often holds several of them.
fn axis_normal(rng: &mut Pcg32) -> Vec3 {
    let base = [
        Vec3::new(0.125, 0.125, 0.75),
        Vec3::new(0.625, 0.125, 0.25),
        Vec3::new(0.125, 0.625, 0.25),
    ];
    let k = rng.next_u32() as usize % 6;
    let d = if k < 3 { base[k] } else { -base[k - 3] }.normalize();
    (d + unit(rng) * rng.uniform(0.0, 0.08)).normalize()
}

/// A query at `p` with an [`axis_normal`] (`ωo` and roughness arbitrary).
fn axis_query(p: Vec3, rng: &mut Pcg32) -> QueryPoint {
    QueryPoint::from_vec3(p, axis_normal(rng), unit(rng), rng.next_f32())
}

/// `n` queries `make(p)` at positions `p` uniform in the box (drawn before
/// each query's other values).
fn queries_in_box(
    n: usize,
    rng: &mut Pcg32,
    make: impl Fn(Vec3, &mut Pcg32) -> QueryPoint,
) -> Vec<QueryPoint> {
    (0..n)
        .map(|_| {
            let p = in_box(rng);
            make(p, rng)
        })
        .collect()
}

/// `n` jitters uniform in the unit cube.
fn random_jitter(n: usize, rng: &mut Pcg32) -> Vec<Vec3> {
    (0..n)
        .map(|_| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()))
        .collect()
}

/// A random unit normal that is a fixed point of
/// `guiding_core::frame::normalize_or`, so normalising it once or twice
/// gives the same bits (about one random unit vector in six is not: its
/// normalisation moves it by an ulp).
fn fixed_unit(rng: &mut Pcg32) -> Vec3 {
    loop {
        let n = normalize_or(unit(rng), Vec3::Z);
        if normalize_or(n, Vec3::Z) == n {
            return n;
        }
    }
}

/// The octahedral normal bin (8 × 8 per the cache's docs) of a normal,
/// written out here: the normal over its L1 norm, the lower hemisphere
/// folded onto the outer triangles, each coordinate's `[−1, 1]` cut in 8.
fn octahedral_bin(n: Vec3) -> u32 {
    let p = n / (n.x.abs() + n.y.abs() + n.z.abs());
    let (x, y) = if p.z >= 0.0 {
        (p.x, p.y)
    } else {
        (
            (1.0 - p.y.abs()).copysign(p.x),
            (1.0 - p.x.abs()).copysign(p.y),
        )
    };
    let b = |t: f32| (((t + 1.0) * 4.0) as u32).min(7);
    b(x) + 8 * b(y)
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

/// `cached`'s answer `(got, lookup, missed)` for `queries` that all hit:
/// every query a hit, the lanes equal to `want` bit for bit, and differing
/// from cell to cell (the comparison has teeth).
fn assert_all_hit_with(
    what: &str,
    queries: &[QueryPoint],
    (got, lookup, missed): &(Vec<Vec<u32>>, CacheLookup, Vec<u32>),
    want: &[Vec<u32>],
) {
    assert_eq!(
        *lookup,
        CacheLookup {
            hits: queries.len() as u64,
            misses: 0
        }
    );
    assert!(missed.is_empty());
    for (k, (g, w)) in got.iter().zip(want).enumerate() {
        assert_eq!(g, w, "{what}: query {k} at {:?}", queries[k].position);
    }
    let distinct: HashSet<&Vec<u32>> = got.iter().collect();
    assert!(distinct.len() > got.len() / 2, "{what}: {}", distinct.len());
}

/// `cache`'s decode of `queries` at the cells' centres (jitter ½), every
/// query a hit.
fn decode_centred(
    cache: &GuideCache,
    field: &GuidingField,
    queries: &[QueryPoint],
) -> DistributionBatch {
    let jitter = vec![Vec3::splat(0.5); queries.len()];
    let mut batch = DistributionBatch::new();
    let mut missed = Vec::new();
    cache
        .decode_batch(field, queries, &jitter, &mut batch, &mut missed)
        .unwrap();
    assert!(missed.is_empty());
    batch
}

/// Fingerprints of the network's decode of `queries`.
fn network(field: &GuidingField, queries: &[QueryPoint]) -> Vec<Vec<u32>> {
    let mut batch = DistributionBatch::new();
    field.decode_batch(queries, &mut batch);
    fingerprints(field, &batch)
}

/// Fingerprints of the network's decode of `queries` times the clamped
/// cosine of `normals` (`DistributionBatch::apply_cosine_product`).
fn network_product(
    field: &GuidingField,
    queries: &[QueryPoint],
    normals: &[Vec3],
) -> Vec<Vec<u32>> {
    let mut batch = DistributionBatch::new();
    field.decode_batch(queries, &mut batch);
    assert!(batch.apply_cosine_product(normals));
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
        let points = queries_at(&positions, &mut rng);
        let cache = field.build_cache(&points, &OPTIONS).unwrap();
        assert!(!cache.has_cosine_product());
        assert_eq!(cache.cells(), positions.len(), "{name}");
        assert_eq!(cache.generation(), field.generation());
        // In another order than the cache's cells, with other normals / ωo.
        let mut queries = queries_at(&positions, &mut rng);
        queries.reverse();
        let answer = cached_centred(&cache, &field, &queries);
        assert_all_hit_with(name, &queries, &answer, &network(&field, &queries));
    }
}

/// A cached batch shares the cache's lanes instead of copying them; changing
/// its lanes in place (the cosine product) copies them in first and leaves
/// the cache as it was, and `get` reads the shared lanes.
#[test]
fn a_cached_batch_shares_the_cells_and_copies_them_before_a_product() {
    let (field, mut rng, empty) = npm_with_empty_cache(71, &OPTIONS);
    let positions = one_position_per_cell(empty.resolution(), &mut rng);
    let points = queries_at(&positions, &mut rng);
    let cache = field.build_cache(&points, &OPTIONS).unwrap();
    let queries = queries_at(&positions, &mut rng);
    let normals: Vec<Vec3> = queries.iter().map(|q| Vec3::from_array(q.normal)).collect();
    let mut batch = decode_centred(&cache, &field, &queries);
    let (dirs, _) = probes();
    for (i, q) in queries.iter().enumerate() {
        let d = field.attach(batch.get(i).unwrap()).unwrap();
        assert_eq!(
            d.pdf(dirs[0]).to_bits(),
            field.distribution(q).pdf(dirs[0]).to_bits(),
            "lane {i}"
        );
    }
    assert!(batch.get(queries.len()).is_none());
    assert!(batch.apply_cosine_product(&normals));
    assert_eq!(
        fingerprints(&field, &batch),
        network_product(&field, &queries, &normals)
    );
    // The cache's own lanes are untouched.
    let (again, _, _) = cached_centred(&cache, &field, &queries);
    assert_eq!(again, network(&field, &queries));
}

/// One sample on every lane of `batch` and the batch's pdf of each sampled
/// direction.
fn sample_every_lane(
    field: &GuidingField,
    batch: &DistributionBatch,
    n: usize,
    rng: &mut Pcg32,
) -> (Vec<DirectionSample>, Vec<f32>) {
    let lanes: Vec<u32> = (0..n as u32).collect();
    let us: Vec<Vec2> = (0..n).map(|_| rng.next_vec2()).collect();
    let zero = DirectionSample {
        direction: Vec3::ZERO,
        pdf: 0.0,
    };
    let mut samples = vec![zero; n];
    field
        .sample_decoded(batch, &lanes, &us, &mut samples)
        .unwrap();
    let dirs: Vec<Vec3> = samples.iter().map(|s| s.direction).collect();
    let mut pdfs = vec![0.0; n];
    field.pdf_decoded(batch, &lanes, &dirs, &mut pdfs).unwrap();
    (samples, pdfs)
}

/// With [`CacheOptions::df_table`] a DF cell is a table: no plain-value
/// lane, samples whose densities are the table's `pdf_decoded`, and at the
/// row centres (directions with `ε₁ = (r + ½)/32` exactly) the network's
/// density, bit for bit; a refresh tabulates again.
#[test]
fn tabulated_df_cells_sample_their_own_density_and_hold_the_network_at_row_centres() {
    use guiding_core::factorised::{direction_from_square, square_from_direction};
    let (_, config) = radiance_presets().remove(3);
    let mut field = trained(config, 81);
    let mut rng = Pcg32::new(82, 1);
    let empty = field.build_cache(&[], &OPTIONS).unwrap();
    let positions = one_position_per_cell(empty.resolution(), &mut rng);
    let points = queries_at(&positions, &mut rng);
    let options = CacheOptions {
        df_table: true,
        ..OPTIONS
    };
    let mut cache = field.build_cache(&points, &options).unwrap();
    for round in 0..2 {
        let queries = queries_at(&positions, &mut rng);
        let batch = decode_centred(&cache, &field, &queries);
        assert!(batch.get(0).is_none(), "a table lane has no plain value");
        let n = queries.len();
        let (samples, pdfs) = sample_every_lane(&field, &batch, n, &mut rng);
        for i in 0..n {
            assert_eq!(
                samples[i].pdf.to_bits(),
                pdfs[i].to_bits(),
                "round {round} lane {i}"
            );
        }
        // Row centres against the network's batched decode at the same points.
        let mut network = DistributionBatch::new();
        field.decode_batch(&queries, &mut network);
        // (Some row centres do not survive the warp's round trip exactly.)
        let (mut centre, mut centre_lanes) = (Vec::new(), Vec::new());
        for i in 0..n {
            let e1 = ((i % 32) as f32 + 0.5) / 32.0;
            let d = (0..64)
                .map(|_| direction_from_square(Vec2::new(e1, rng.uniform(0.02, 0.98))))
                .find(|&d| square_from_direction(d).x == e1);
            if let Some(d) = d {
                centre.push(d);
                centre_lanes.push(i as u32);
            }
        }
        assert!(centre.len() > n / 2, "{} of {n} row centres", centre.len());
        let m = centre.len();
        let (mut got, mut want) = (vec![0.0; m], vec![0.0; m]);
        field
            .pdf_decoded(&batch, &centre_lanes, &centre, &mut got)
            .unwrap();
        field
            .pdf_decoded(&network, &centre_lanes, &centre, &mut want)
            .unwrap();
        for k in 0..m {
            assert_eq!(
                got[k].to_bits(),
                want[k].to_bits(),
                "round {round} lane {}",
                centre_lanes[k]
            );
        }
        // Train on and refresh: the tables follow the new parameters.
        train_once(&mut field, &mut rng);
        cache.refresh(&field).unwrap();
    }
}

/// A tabulated DF cache's misses are tabulated too: a batch that mixes
/// cells and misses is of one kind, so it can be copied out of the shared
/// cells (`apply_cosine_product` does, and used to panic on DF tables mixed
/// with network vertices) and samples its own density on every lane.
#[test]
fn tabulated_df_misses_are_tables_too() {
    let (_, config) = radiance_presets().remove(3);
    let field = trained(config, 91);
    let mut rng = Pcg32::new(92, 1);
    let options = CacheOptions {
        df_table: true,
        ..OPTIONS
    };
    // Cells only in the lower half of the box along x.
    let low: Vec<Vec3> = (0..200)
        .map(|_| {
            let p = in_box(&mut rng);
            Vec3::new(LO[0] + 0.25 * (p.x - LO[0]), p.y, p.z)
        })
        .collect();
    let cache = field
        .build_cache(&queries_at(&low, &mut rng), &options)
        .unwrap();
    let mut positions: Vec<Vec3> = low[..32].to_vec();
    positions.extend((0..32).map(|_| {
        let p = in_box(&mut rng);
        Vec3::new(HI[0] - 0.1 * (HI[0] - p.x), p.y, p.z)
    }));
    let queries = queries_at(&positions, &mut rng);
    let jitter = vec![Vec3::splat(0.5); queries.len()];
    let mut batch = DistributionBatch::new();
    let mut missed = Vec::new();
    let lookup = cache
        .decode_batch(&field, &queries, &jitter, &mut batch, &mut missed)
        .unwrap();
    assert!(lookup.hits >= 32 && lookup.misses > 0, "{lookup:?}");
    let normals: Vec<Vec3> = queries.iter().map(|q| Vec3::from_array(q.normal)).collect();
    assert!(
        !batch.apply_cosine_product(&normals),
        "DF has no cosine product"
    );
    let n = queries.len();
    let (samples, pdfs) = sample_every_lane(&field, &batch, n, &mut rng);
    for i in 0..n {
        assert!(
            samples[i].pdf > 0.0 && samples[i].pdf.is_finite(),
            "lane {i}"
        );
        assert_eq!(samples[i].pdf.to_bits(), pdfs[i].to_bits(), "lane {i}");
    }
}

#[test]
fn build_cache_refuses_product_targets_and_bad_resolutions() {
    let products = [
        GuidingConfig::npm_product(),
        GuidingConfig::nasg_product(),
        GuidingConfig::df_linear().with_target(Target::Product),
    ];
    let p = [QueryPoint::from_vec3(
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::Z,
        Vec3::Z,
        1.0,
    )];
    for config in products {
        let field = GuidingField::new(config.with_size(ModelSize::Small), LO, HI).unwrap();
        for options in [OPTIONS, PRODUCT] {
            assert!(
                matches!(
                    field.build_cache(&p, &options),
                    Err(GuidingError::InvalidConfig(_))
                ),
                "{config:?} {options:?}"
            );
        }
    }
    let field = GuidingField::new(radiance_presets()[0].1, LO, HI).unwrap();
    for cosine_product in [false, true] {
        for resolution in [0, 257, u32::MAX] {
            let options = CacheOptions {
                resolution,
                cosine_product,
                df_table: false,
            };
            assert!(
                matches!(
                    field.build_cache(&p, &options),
                    Err(GuidingError::InvalidConfig(_))
                ),
                "resolution {resolution}"
            );
        }
        for (resolution, res) in [(1, [3, 3, 3]), (256, [130, 258, 194])] {
            let options = CacheOptions {
                resolution,
                cosine_product,
                df_table: false,
            };
            let cache = field.build_cache(&p, &options).unwrap();
            assert_eq!(cache.resolution(), res, "resolution {resolution}");
            assert_eq!(cache.cell_size(), 4.0 / resolution as f32);
            assert_eq!(cache.cells(), 1);
            assert_eq!(cache.has_cosine_product(), cosine_product);
        }
    }
}

/// The radiance presets with [`OPTIONS`], and NPM with [`PRODUCT`].
fn cache_variants() -> Vec<(&'static str, GuidingConfig, CacheOptions)> {
    let mut v: Vec<_> = radiance_presets()
        .into_iter()
        .map(|(n, c)| (n, c, OPTIONS))
        .collect();
    v.push(("npm-cos", radiance_presets()[0].1, PRODUCT));
    v
}

#[test]
fn a_stale_cache_is_refused_and_refresh_equals_a_fresh_build() {
    for (i, (name, config, options)) in cache_variants().into_iter().enumerate() {
        let mut field = trained(config, 30 + i as u64);
        let other = trained(config, 40 + i as u64);
        let mut rng = Pcg32::new(50 + i as u64, 1);
        // Many points per cell (and per normal bin): the decode points are
        // centroids, the product normals means.
        let positions = queries_in_box(3000, &mut rng, axis_query);
        let mut cache = field.build_cache(&positions, &options).unwrap();
        assert_eq!(cache.has_cosine_product(), options.cosine_product);
        let queries = queries_in_box(200, &mut rng, axis_query);
        let jitter = random_jitter(queries.len(), &mut rng);
        let before = cached(&cache, &field, &queries, &jitter);
        assert!(
            before.1.hits > queries.len() as u64 / 2,
            "{name}: {:?}",
            before.1
        );
        let before = before.0;
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
        let fresh = field.build_cache(&positions, &options).unwrap();
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

/// The lane a point makes (and a lookup without jitter reads), computed
/// independently: its cell, and with the cosine product its normal's bin.
fn lane_key(cache: &GuideCache, q: &QueryPoint) -> Option<([u32; 3], u32)> {
    let cell = cell_of(cache, Vec3::from_array(q.position))?;
    let bin = if cache.has_cosine_product() {
        octahedral_bin(Vec3::from_array(q.normal))
    } else {
        0
    };
    Some((cell, bin))
}

#[test]
fn extend_is_order_independent_counts_new_lanes_and_ignores_bad_positions() {
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
    for (i, (name, config, options)) in cache_variants().into_iter().enumerate() {
        let field = trained(config, 60 + i as u64);
        let mut rng = Pcg32::new(70 + i as u64, 1);
        let invalid: Vec<QueryPoint> = invalid.iter().map(|&p| axis_query(p, &mut rng)).collect();
        // Points in the lower half of the box (z < 1.5), a few just outside
        // its faces (inside the grid's one-cell margin), with normals near
        // the axes (several per bin), repeated points and the invalid ones
        // mixed in.
        let mut points: Vec<QueryPoint> = (0..1500)
            .map(|_| {
                let p = in_box(&mut rng);
                axis_query(Vec3::new(p.x * 1.1, p.y * 1.05, p.z * 0.5 - 0.1), &mut rng)
            })
            .collect();
        let repeats: Vec<QueryPoint> = points[..100].to_vec();
        points.extend(repeats);
        points.extend_from_slice(&invalid);
        let distinct = |ps: &[QueryPoint], cache: &GuideCache| -> HashSet<([u32; 3], u32)> {
            ps.iter().filter_map(|q| lane_key(cache, q)).collect()
        };

        let mut a = field.build_cache(&[], &options).unwrap();
        let want_lanes = distinct(&points, &a);
        if options.cosine_product {
            // Several bins per cell and several points per bin.
            let cells: HashSet<[u32; 3]> = want_lanes.iter().map(|k| k.0).collect();
            assert!(
                want_lanes.len() > 2 * cells.len() && want_lanes.len() < points.len() * 3 / 4,
                "{name}: {} lanes in {} cells",
                want_lanes.len(),
                cells.len()
            );
        }
        assert_eq!(a.extend(&field, &points).unwrap(), want_lanes.len());
        assert_eq!(a.cells(), want_lanes.len(), "{name}");
        assert_eq!(a.extend(&field, &points).unwrap(), 0);

        // Shuffled (Fisher–Yates): the same lanes, decode points and normals.
        let mut shuffled = points.clone();
        for k in (1..shuffled.len()).rev() {
            let j = rng.next_u32() as usize % (k + 1);
            shuffled.swap(k, j);
        }
        let b = field.build_cache(&shuffled, &options).unwrap();
        assert_eq!(b.cells(), a.cells());
        // Random queries with normals near the axes, and the points
        // themselves (their own bins: hits even with the product).
        let mut queries: Vec<QueryPoint> = (0..400)
            .map(|_| {
                let p = in_box(&mut rng);
                axis_query(Vec3::new(p.x, p.y, p.z * 0.5), &mut rng)
            })
            .collect();
        queries.extend_from_slice(&points[..400]);
        let jitter = random_jitter(queries.len(), &mut rng);
        let (fa, la, ma) = cached(&a, &field, &queries, &jitter);
        let (fb, lb, mb) = cached(&b, &field, &queries, &jitter);
        assert_eq!((la, &ma), (lb, &mb), "{name}");
        if options.cosine_product {
            // Points' own bins are always there; random ones mostly.
            assert!(ma.iter().all(|&m| m < 400), "{name}: {ma:?}");
            assert!(la.misses < 100, "{name}: {la:?}");
        } else {
            assert_eq!(
                la.misses, 0,
                "{name}: every query is inside an occupied cell"
            );
        }
        for (k, (x, y)) in fa.iter().zip(&fb).enumerate() {
            assert_eq!(x, y, "{name}: query {k}");
        }

        // Invalid positions alone add nothing.
        let lanes = a.cells();
        assert_eq!(a.extend(&field, &invalid).unwrap(), 0, "{name}");
        assert_eq!(a.cells(), lanes);

        // New points overlapping the occupied half: as many lanes as new
        // distinct (cell, bin) keys among them.
        let upper: Vec<QueryPoint> = (0..300)
            .map(|_| {
                let p = in_box(&mut rng);
                axis_query(Vec3::new(p.x, p.y, 1.0 + p.z * 0.5), &mut rng)
            })
            .collect();
        let old = distinct(&points, &a);
        let new = distinct(&upper, &a);
        let added = new.difference(&old).count();
        assert!(added > 0 && added < new.len(), "{name}: {added}");
        assert_eq!(a.extend(&field, &upper).unwrap(), added, "{name}");
        assert_eq!(a.cells(), lanes + added);

        // Misses: invalid query positions and one in the box but with no
        // occupied cell near (the cache `b` holds the lower half only),
        // between hits; they are the network's decode of the query (times
        // the query's own clamped cosine with the product).
        let mut mixed: Vec<QueryPoint> = Vec::new();
        let mut want_missed = Vec::new();
        let far = [Vec3::new(0.0, 0.0, 2.9), Vec3::new(-0.9, 1.9, 2.8)];
        let far: Vec<QueryPoint> = far.iter().map(|&p| axis_query(p, &mut rng)).collect();
        for (k, &q) in invalid.iter().chain(&far).enumerate() {
            mixed.push(points[k]);
            want_missed.push(mixed.len() as u32);
            mixed.push(q);
        }
        let jitter = random_jitter(mixed.len(), &mut rng);
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
            let q1 = std::slice::from_ref(&q);
            let want = if options.cosine_product {
                network_product(&field, q1, &[Vec3::from_array(q.normal)])
            } else {
                network(&field, q1)
            };
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
    let cells: Vec<(f64, f64)> = probabilities
        .iter()
        .zip(observed)
        .filter(|(&w, _)| w > 0.0)
        .map(|(&w, &o)| (w * n, o as f64))
        .collect();
    let (kept, low) = pool_low_cells(cells, MIN_EXPECTED);
    let statistic = pearson_statistic(&kept);
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
    let mut rng = Pcg32::new(91, 1);
    let cache = field
        .build_cache(&queries_at(&centres, &mut rng), &OPTIONS)
        .unwrap();
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

// ---------------------------------------------------------------------------
// The cosine product per normal bin.

/// Fingerprints of the cache's lanes for `queries`, every jitter ½ (the
/// query's own cell).
fn cached_centred(
    cache: &GuideCache,
    field: &GuidingField,
    queries: &[QueryPoint],
) -> (Vec<Vec<u32>>, CacheLookup, Vec<u32>) {
    cached(
        cache,
        field,
        queries,
        &vec![Vec3::splat(0.5); queries.len()],
    )
}

/// A query at `p` with normal `n` (`ωo` and roughness arbitrary).
fn at(p: Vec3, n: Vec3, rng: &mut Pcg32) -> QueryPoint {
    QueryPoint::from_vec3(p, n, unit(rng), rng.next_f32())
}

/// The NPM radiance field (small) of the cosine-product tests.
fn npm(seed: u64) -> GuidingField {
    trained(radiance_presets()[0].1, seed)
}

/// [`npm`] of `seed`, an RNG of seed `seed + 1` and the field's empty cache
/// under `options` (its grid, for positions and cell centres).
fn npm_with_empty_cache(seed: u64, options: &CacheOptions) -> (GuidingField, Pcg32, GuideCache) {
    let field = npm(seed);
    let rng = Pcg32::new(seed + 1, 1);
    let empty = field.build_cache(&[], options).unwrap();
    (field, rng, empty)
}

/// The density of lane `lane` of `lanes` as a function of the direction.
fn lane_pdf<'a>(
    field: &'a GuidingField,
    lanes: &'a DistributionBatch,
    lane: u32,
) -> impl Fn(Vec3) -> f32 + 'a {
    move |wi| {
        let mut q = [0.0];
        field.pdf_decoded(lanes, &[lane], &[wi], &mut q).unwrap();
        q[0]
    }
}

#[test]
fn a_product_lookup_at_the_only_point_of_its_lane_is_the_network_decode_times_its_cosine() {
    let (field, mut rng, empty) = npm_with_empty_cache(110, &PRODUCT);
    assert!(empty.has_cosine_product());
    let positions = one_position_per_cell(empty.resolution(), &mut rng);
    // One point per cell with a random normal (one bin each); the normals
    // are fixed points of normalisation (see `fixed_unit`).
    let points: Vec<QueryPoint> = positions
        .iter()
        .map(|&p| at(p, fixed_unit(&mut rng), &mut rng))
        .collect();
    let cache = field.build_cache(&points, &PRODUCT).unwrap();
    assert_eq!(cache.cells(), points.len());
    // In another order, with other ωo and roughness, the same normals.
    let mut queries: Vec<QueryPoint> = points
        .iter()
        .map(|q| {
            at(
                Vec3::from_array(q.position),
                Vec3::from_array(q.normal),
                &mut rng,
            )
        })
        .collect();
    queries.reverse();
    let normals: Vec<Vec3> = queries.iter().map(|q| Vec3::from_array(q.normal)).collect();
    let answer = cached_centred(&cache, &field, &queries);
    let want = network_product(&field, &queries, &normals);
    assert_all_hit_with("product", &queries, &answer, &want);
    // The product changed the lanes.
    let plain = network(&field, &queries);
    assert!(answer.0.iter().zip(&plain).all(|(g, p)| g != p));
}

#[test]
fn product_lanes_are_per_normal_bin_with_the_normalised_mean_normal() {
    let (field, mut rng, empty) = npm_with_empty_cache(120, &PRODUCT);
    let h = empty.cell_size();
    // Cell 1: two points, normals +z and +x (bins 36 and 39): two lanes.
    let c1 = cell_centre(&empty, [3, 4, 3]);
    let (p1, p2) = (c1 + Vec3::new(0.125, 0.0, -0.0625), c1 - Vec3::splat(0.125));
    // Cell 2: two points whose normals differ but share a bin: one lane.
    let c2 = cell_centre(&empty, [1, 6, 2]);
    let (p3, p4) = (
        c2 + Vec3::new(0.1, 0.05, 0.0),
        c2 - Vec3::new(0.0625, 0.1, 0.2),
    );
    let n3 = Vec3::new(0.05, 0.2, 1.0).normalize();
    let n4 = Vec3::new(0.2, 0.05, 1.0).normalize();
    let (bz, bx) = (octahedral_bin(Vec3::Z), octahedral_bin(Vec3::X));
    assert_ne!(bz, bx);
    assert_eq!((octahedral_bin(n3), octahedral_bin(n4)), (bz, bz));
    let points = [
        at(p1, Vec3::Z, &mut rng),
        at(p2, Vec3::X, &mut rng),
        at(p3, n3, &mut rng),
        at(p4, n4, &mut rng),
    ];
    let cache = field.build_cache(&points, &PRODUCT).unwrap();
    assert_eq!(cache.cells(), 3);
    assert_eq!(cache.cell_size(), h);

    // Cell 1: the bin of the query's normal picks the lane, wherever in the
    // cell the query is (the jitter random: the neighbours are empty).
    let nx = Vec3::new(1.0, 0.1, 0.1).normalize();
    assert_eq!(octahedral_bin(nx), bx);
    let queries = [
        at(p1, Vec3::Z, &mut rng),
        at(p2, Vec3::Z, &mut rng),
        at(c1, Vec3::new(0.1, 0.1, 1.0).normalize(), &mut rng),
        at(p2, Vec3::X, &mut rng),
        at(p1, Vec3::X, &mut rng),
        at(c1, nx, &mut rng),
    ];
    let jitter = random_jitter(queries.len(), &mut rng);
    let (got, lookup, _) = cached(&cache, &field, &queries, &jitter);
    assert_eq!(lookup.misses, 0);
    let lane_z = network_product(&field, &points[..1], &[Vec3::Z]);
    let lane_x = network_product(&field, &points[1..2], &[Vec3::X]);
    assert_ne!(lane_z, lane_x);
    for (k, g) in got.iter().enumerate() {
        let want = if k < 3 { &lane_z[0] } else { &lane_x[0] };
        assert_eq!(g, want, "cell 1, query {k}");
    }
    // A bin cell 1 does not have (−z) misses.
    let (_, lookup, missed) = cached_centred(&cache, &field, &[at(c1, -Vec3::Z, &mut rng)]);
    assert_eq!((lookup.misses, missed), (1, vec![0]));

    // Cell 2: one lane, decoded at the centroid (an f64 mean) times the
    // clamped cosine of the mean normal (normalised once, by the product).
    let mean = |a: Vec3, b: Vec3| {
        let (a, b) = (a.as_dvec3(), b.as_dvec3());
        ((a + b) / 2.0).as_vec3()
    };
    let centroid = at(mean(p3, p4), Vec3::Z, &mut rng);
    let normal = mean(n3, n4);
    let want = network_product(&field, &[centroid], &[normal]);
    for q in [
        at(p3, n3, &mut rng),
        at(p4, n3, &mut rng),
        at(c2, Vec3::Z, &mut rng),
    ] {
        let (got, lookup, _) = cached_centred(&cache, &field, &[q]);
        assert_eq!(lookup.misses, 0);
        assert_eq!(got, want, "cell 2 at {:?}", q.position);
    }
    // Neither point's own normal (nor the centroid's plain decode).
    for n in [n3, n4] {
        assert_ne!(want, network_product(&field, &[centroid], &[n]));
    }
    assert_ne!(want, network(&field, &[centroid]));
}

#[test]
fn a_product_miss_is_the_network_decode_times_the_query_cosine() {
    let (field, mut rng, empty) = npm_with_empty_cache(130, &PRODUCT);
    let positions = one_position_per_cell(empty.resolution(), &mut rng);
    // Every lane has the normal +z.
    let points: Vec<QueryPoint> = positions
        .iter()
        .map(|&p| at(p, Vec3::Z, &mut rng))
        .collect();
    let cache = field.build_cache(&points, &PRODUCT).unwrap();
    assert_eq!(cache.cells(), points.len());
    let lanes = network_product(&field, &points, &vec![Vec3::Z; points.len()]);
    // Misses: occupied cells but a bin they lack (random normals away
    // from +z, one of them not unit), positions off the grid and
    // non-finite ones; between them hits (+z at the points).
    let mut misses = Vec::new();
    for (k, &p) in positions[..6].iter().enumerate() {
        let mut n = unit(&mut rng);
        while octahedral_bin(n) == octahedral_bin(Vec3::Z) {
            n = unit(&mut rng);
        }
        misses.push(at(p, if k == 0 { n * 2.5 } else { n }, &mut rng));
    }
    for p in [
        Vec3::new(100.0, 0.0, 1.0),
        Vec3::new(0.0, -3.5, 1.0),
        Vec3::new(0.0, f32::NAN, 1.0),
    ] {
        misses.push(at(p, unit(&mut rng), &mut rng));
    }
    let mut mixed = Vec::new();
    let mut want_missed = Vec::new();
    for (k, &q) in misses.iter().enumerate() {
        mixed.push(points[10 + k]);
        want_missed.push(mixed.len() as u32);
        mixed.push(q);
    }
    let (got, lookup, missed) = cached_centred(&cache, &field, &mixed);
    assert_eq!(missed, want_missed);
    assert_eq!(lookup.misses, misses.len() as u64);
    for (k, g) in got.iter().enumerate() {
        let q = mixed[k];
        if k % 2 == 0 {
            assert_eq!(g, &lanes[10 + k / 2], "hit {k}");
        } else {
            let q1 = std::slice::from_ref(&q);
            let n = Vec3::from_array(q.normal);
            assert_eq!(g, &network_product(&field, q1, &[n])[0], "miss {k}");
            assert_ne!(g, &network(&field, q1)[0], "miss {k}: no product");
            assert_ne!(
                g,
                &network_product(&field, q1, &[Vec3::Z])[0],
                "miss {k}: the lanes' normal"
            );
        }
    }
}

#[test]
fn nasg_and_df_ignore_the_cosine_product() {
    for (i, (name, config)) in radiance_presets().into_iter().enumerate().skip(1) {
        let field = trained(config, 140 + i as u64);
        let mut rng = Pcg32::new(150 + i as u64, 1);
        let points = queries_in_box(1000, &mut rng, axis_query);
        let plain = field.build_cache(&points, &OPTIONS).unwrap();
        let product = field.build_cache(&points, &PRODUCT).unwrap();
        assert!(!product.has_cosine_product(), "{name}");
        assert_eq!(product.cells(), plain.cells(), "{name}");
        let cells: HashSet<[u32; 3]> = points
            .iter()
            .filter_map(|q| cell_of(&plain, Vec3::from_array(q.position)))
            .collect();
        assert_eq!(product.cells(), cells.len(), "{name}: a lane per cell");
        let queries = queries_in_box(300, &mut rng, query);
        let jitter = random_jitter(queries.len(), &mut rng);
        let a = cached(&plain, &field, &queries, &jitter);
        let b = cached(&product, &field, &queries, &jitter);
        assert_eq!(a, b, "{name}");
    }
    // NPM does not (the comparison above would see the product).
    let field = npm(149);
    let mut rng = Pcg32::new(159, 1);
    let points = queries_in_box(300, &mut rng, axis_query);
    let plain = field.build_cache(&points, &OPTIONS).unwrap();
    let product = field.build_cache(&points, &PRODUCT).unwrap();
    assert!(product.has_cosine_product() && !plain.has_cosine_product());
    assert!(product.cells() > plain.cells());
    let a = cached_centred(&plain, &field, &points[..50]);
    let b = cached_centred(&product, &field, &points[..50]);
    assert!(a.0.iter().zip(&b.0).all(|(x, y)| x != y));
}

// ---------------------------------------------------------------------------
// The per-cell selection fit.

/// Candidates of the fit: `CANDIDATES` values evenly spaced over `[min, max]`.
fn candidate(fit: &SelectionFit, k: usize) -> f32 {
    fit.min + (fit.max - fit.min) * k as f32 / (guiding::cache::CANDIDATES - 1) as f32
}

/// `F = Y(L ⊙ f cos)`: the luminance of a sample's integrand, in `f64`.
fn integrand(s: &TrainingSample, radiance: &dyn Fn(&TrainingSample) -> [f32; 3]) -> f64 {
    [0.2126, 0.7152, 0.0722]
        .iter()
        .zip(radiance(s).iter().zip(&s.bsdf_cos))
        .map(|(y, (&l, &b))| y * f64::from(l) * f64::from(b))
        .sum()
}

/// The second-moment estimator of `fit_selection`'s docs, written out:
/// `M̂(c) = Σ F² / ((c·q + (1 − c)·p_bsdf) · p_s)`, `F` the luminance of
/// `L ⊙ f cos` with `L = radiance(sample)`, over the samples given (all
/// usable; a candidate density 0 where `F ≠ 0` makes its sum infinite).
fn moments(
    fit: &SelectionFit,
    samples: &[(TrainingSample, f32)],
    radiance: &dyn Fn(&TrainingSample) -> [f32; 3],
) -> Vec<f64> {
    (0..guiding::cache::CANDIDATES)
        .map(|k| {
            let c = f64::from(candidate(fit, k));
            samples
                .iter()
                .map(|(s, q)| {
                    let f = integrand(s, radiance);
                    let p = c * f64::from(*q) + (1.0 - c) * f64::from(s.bsdf_pdf);
                    f * f / (p * f64::from(s.sample_pdf))
                })
                .sum()
        })
        .collect()
}

/// `report.variance_ratio` written out from its docs: per lane with
/// samples `V(c) = M̂(c) − (Σ F/p_s)² / n` at the lane's fitted `c` and at
/// `c = 0`, each summed over the lanes, then their ratio; with the bound of
/// its difference to `fit_selection`'s value. That one forms `F` in `f32`
/// (a relative error below 2⁻²² from three products and two sums), so each
/// `F²` term, and each sum of them, is off by a relative 2⁻²¹ at most, and
/// `V = M̂ − mean term` (which cancels where the guide matches the
/// integrand) by `2⁻²¹ (M̂ + mean term)`.
fn expected_variance_ratio(
    fit: &SelectionFit,
    sets: &[Option<&[(TrainingSample, f32)]>],
    fitted: &[f32],
    radiance: &dyn Fn(&TrainingSample) -> [f32; 3],
) -> (f64, f64) {
    let (mut v_fit, mut v_bsdf) = (0.0f64, 0.0f64);
    let (mut e_fit, mut e_bsdf) = (0.0f64, 0.0f64);
    for (set, &c) in sets.iter().zip(fitted) {
        let Some(set) = set else { continue };
        let m = moments(fit, set, radiance);
        let sum: f64 = set
            .iter()
            .map(|(s, _)| integrand(s, radiance) / f64::from(s.sample_pdf))
            .sum();
        let mean_term = sum * sum / set.len() as f64;
        let j = (0..m.len())
            .find(|&k| candidate(fit, k) == c)
            .expect("a fitted value is a candidate");
        v_fit += m[j] - mean_term;
        v_bsdf += m[0] - mean_term;
        e_fit += m[j] + mean_term;
        e_bsdf += m[0] + mean_term;
    }
    let ratio = v_fit / v_bsdf;
    let eps = 2f64.powi(-21);
    let bound =
        eps * (e_fit + ratio.abs() * e_bsdf) / (v_bsdf.abs() * (1.0 - eps * e_bsdf / v_bsdf.abs()));
    (ratio, bound)
}

/// The candidate minimising `moments` (the first of equal minima; `max`
/// if every sum is infinite).
/// `Σ F / p_s` over `samples` (the first moment of the fit's estimator).
fn first_sum(
    samples: &[(TrainingSample, f32)],
    radiance: &dyn Fn(&TrainingSample) -> [f32; 3],
) -> f64 {
    samples
        .iter()
        .map(|(s, _)| integrand(s, radiance) / f64::from(s.sample_pdf))
        .sum()
}

/// The candidate of least variance times cost, as `SelectionFit::guide_cost`'s docs say:
/// `s (M̂(c) − mean) / v_ref + κ [c > 0] n / N` (`vertex_share = n / N`); the plain `M̂(c)`
/// without a cost (or without a positive `v_ref`); the first of equals; every candidate
/// infinite: `max`.
fn argmin(fit: &SelectionFit, m: &[f64], mean: f64, v_ref: f64, vertex_share: f64) -> f32 {
    let kappa = if v_ref > 0.0 && v_ref.is_finite() {
        f64::from(fit.guide_cost)
    } else {
        0.0
    };
    let s = f64::from(fit.variance_share);
    let score = |k: usize| {
        if kappa > 0.0 {
            let cost = if candidate(fit, k) > 0.0 {
                kappa * vertex_share
            } else {
                0.0
            };
            s * (m[k] - mean) / v_ref + cost
        } else {
            m[k]
        }
    };
    let best = (0..m.len()).fold(0, |b, k| if score(k) < score(b) { k } else { b });
    if m[best].is_finite() {
        candidate(fit, best)
    } else {
        fit.max
    }
}

#[test]
fn fit_selection_refuses_nasg_bad_ranges_and_stale_fields() {
    let mut rng = Pcg32::new(160, 1);
    let points = queries_in_box(100, &mut rng, axis_query);
    let sample = TrainingSample::new(
        points[0],
        [0.0, 0.0, 1.0],
        [1.0; 3],
        INV_FOUR_PI,
        INV_FOUR_PI,
        [1.0; 3],
    );
    let samples = vec![sample; 100];
    let nasg = trained(radiance_presets()[1].1, 161);
    for options in [OPTIONS, PRODUCT] {
        let mut cache = nasg.build_cache(&points, &options).unwrap();
        let r = cache.fit_selection(&nasg, &samples, None, None, &SelectionFit::default());
        assert!(matches!(r, Err(GuidingError::InvalidConfig(_))), "{r:?}");
    }
    let mut field = npm(162);
    let mut cache = field.build_cache(&points, &PRODUCT).unwrap();
    for (min, max) in [(-0.1, 0.5), (0.6, 0.5), (0.1, 1.0), (f32::NAN, 0.5)] {
        let fit = SelectionFit {
            min,
            max,
            ..SelectionFit::default()
        };
        let r = cache.fit_selection(&field, &samples, None, None, &fit);
        assert!(
            matches!(r, Err(GuidingError::InvalidConfig(_))),
            "[{min}, {max}]: {r:?}"
        );
    }
    let fit = SelectionFit::default();
    assert!(cache
        .fit_selection(&field, &samples, None, None, &fit)
        .is_ok());
    let mis = vec![[1.0; 3]; samples.len()];
    assert!(cache
        .fit_selection(&field, &samples, Some(&mis), None, &fit)
        .is_ok());
    let r = cache.fit_selection(&field, &samples, Some(&mis[1..]), None, &fit);
    assert!(
        matches!(r, Err(GuidingError::LengthMismatch { .. })),
        "{r:?}"
    );
    train_once(&mut field, &mut rng);
    let r = cache.fit_selection(&field, &samples, None, None, &fit);
    assert!(
        matches!(r, Err(GuidingError::StaleDistribution { .. })),
        "{r:?}"
    );
}

/// The fit of `fit_selection`'s docs per lane, from the sample sets of the
/// lanes (`None`: a lane with no samples): the argmin of the lane's sums
/// plus `prior_samples` pseudo-samples of the mean over all samples,
/// `M̂(c) + n₀ · M̂_all(c) / N`; a lane without samples takes the argmin of
/// `M̂_all`. Returns the per-lane values and the global one.
fn expected_fit(
    fit: &SelectionFit,
    sets: &[Option<&[(TrainingSample, f32)]>],
    radiance: &dyn Fn(&TrainingSample) -> [f32; 3],
) -> (Vec<f32>, f32) {
    let all: Vec<(TrainingSample, f32)> = sets
        .iter()
        .flatten()
        .flat_map(|s| s.iter())
        .copied()
        .collect();
    let total = moments(fit, &all, radiance);
    let first_all = first_sum(&all, radiance);
    let mean_all = first_all * first_all / all.len() as f64;
    // The whole set's variance at its best constant `c`.
    let v_ref = total
        .iter()
        .map(|m| m - mean_all)
        .filter(|v| v.is_finite())
        .fold(f64::INFINITY, f64::min);
    let global = argmin(fit, &total, mean_all, v_ref, 1.0);
    let weight = f64::from(fit.prior_samples) / all.len() as f64;
    let lanes = sets
        .iter()
        .map(|set| match set {
            Some(set) if !set.is_empty() => {
                let own = moments(fit, set, radiance);
                let shrunk: Vec<f64> = own
                    .iter()
                    .zip(&total)
                    .map(|(m, t)| if weight > 0.0 { m + weight * t } else { *m })
                    .collect();
                // The shrunk sums' mean term: `prior_samples` pseudo-samples of all.
                let n = set.len() as f64 + weight * all.len() as f64;
                let f = first_sum(set, radiance) + weight * first_all;
                argmin(fit, &shrunk, f * f / n, v_ref, n / all.len() as f64)
            }
            _ => global,
        })
        .collect();
    (lanes, global)
}

/// The synthetic training samples of the fit tests, in lane `lane`'s cell
/// `cell` with normals in `normal`'s bin (jittered around it), uniform
/// directions with guide density `q(wi)` (NaN off the lanes), gray
/// radiance `radiance(q, wi)`, BSDF density 1/4π.
fn fit_samples(
    n: usize,
    cell: Vec3,
    h: f32,
    normal: Vec3,
    q: &dyn Fn(Vec3) -> f32,
    radiance: &dyn Fn(f32, Vec3) -> f32,
    rng: &mut Pcg32,
) -> Vec<(TrainingSample, f32)> {
    (0..n)
        .map(|_| {
            let off = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
            let p = cell + off * 0.9 * h;
            let mut nn = (normal + unit(rng) * 0.1).normalize();
            while octahedral_bin(nn) != octahedral_bin(normal) {
                nn = (normal + unit(rng) * 0.1).normalize();
            }
            let wi = unit(rng);
            let qk = q(wi);
            let vertex = QueryPoint::from_vec3(p, nn, unit(rng), 1.0);
            let s = TrainingSample::new(
                vertex,
                wi.to_array(),
                [radiance(qk, wi); 3],
                INV_FOUR_PI * rng.uniform(0.5, 1.5),
                INV_FOUR_PI,
                [rng.uniform(0.5, 1.0); 3],
            );
            (s, qk)
        })
        .collect()
}

/// The selection probabilities the cache hands out for `queries` (jitter
/// ½), and which queries missed.
fn selections(
    cache: &GuideCache,
    field: &GuidingField,
    queries: &[QueryPoint],
) -> (Vec<f32>, Vec<u32>) {
    let mut batch = DistributionBatch::new();
    let mut missed = Vec::new();
    cache
        .decode_batch(
            field,
            queries,
            &vec![Vec3::splat(0.5); queries.len()],
            &mut batch,
            &mut missed,
        )
        .unwrap();
    let c = (0..queries.len())
        .map(|k| batch.selection_probability(k))
        .collect();
    (c, missed)
}

#[test]
fn fit_selection_is_the_argmin_of_the_shrunk_second_moment_per_lane() {
    let (field, mut rng, empty) = npm_with_empty_cache(170, &PRODUCT);
    let h = empty.cell_size();
    let centre = |c: [u32; 3]| cell_centre(&empty, c);
    // Lanes: A (+z) and A' (−z) in one cell, B (+x), C (+z), E (+z, no
    // samples); one point each.
    let (ca, cb, cc, ce) = (
        centre([2, 3, 2]),
        centre([4, 6, 4]),
        centre([3, 2, 5]),
        centre([5, 2, 3]),
    );
    let lane_points = [
        at(ca, Vec3::Z, &mut rng),
        at(ca + Vec3::splat(0.0625), -Vec3::Z, &mut rng),
        at(cb, Vec3::X, &mut rng),
        at(cc, Vec3::Z, &mut rng),
        at(ce, Vec3::Z, &mut rng),
    ];
    let mut cache = field.build_cache(&lane_points, &PRODUCT).unwrap();
    assert_eq!(cache.cells(), 5);
    // The known guide densities: a lane is the decode at its point times
    // the clamped cosine of its normal (bit for bit, tested above).
    let mut lanes = DistributionBatch::new();
    field.decode_batch(&lane_points, &mut lanes);
    let normals: Vec<Vec3> = lane_points
        .iter()
        .map(|q| Vec3::from_array(q.normal))
        .collect();
    assert!(lanes.apply_cosine_product(&normals));
    let q_of = |lane: u32| lane_pdf(&field, &lanes, lane);
    let none = |_: Vec3| f32::NAN;
    // A: the radiance follows the guide (strong); B: half guide, half
    // uniform (an optimum inside the range); A' and C: few samples, uniform
    // (the BSDF fits: on their own the guide would be off); then samples no
    // lane takes (a cell with no point, a bin cell A lacks).
    let follows = |q: f32, _: Vec3| 30.0 * q;
    let half = |q: f32, _: Vec3| 0.5 * q + 0.5 * INV_FOUR_PI;
    let flat = |_: f32, _: Vec3| 0.5;
    let a = fit_samples(300, ca, h, Vec3::Z, &q_of(0), &follows, &mut rng);
    let a2 = fit_samples(40, ca, h, -Vec3::Z, &q_of(1), &flat, &mut rng);
    let b = fit_samples(300, cb, h, Vec3::X, &q_of(2), &half, &mut rng);
    let c = fit_samples(20, cc, h, Vec3::Z, &q_of(3), &flat, &mut rng);
    let off = fit_samples(50, centre([1, 1, 1]), h, Vec3::Z, &none, &flat, &mut rng);
    let off_bin = fit_samples(30, ca, h, Vec3::X, &none, &flat, &mut rng);
    // Unusable samples in lane A: non-finite radiance, a zero sampling
    // density, a negative BSDF density.
    let mut bad = fit_samples(3, ca, h, Vec3::Z, &q_of(0), &follows, &mut rng);
    bad[0].0.radiance[1] = f32::NAN;
    bad[1].0.sample_pdf = 0.0;
    bad[2].0.bsdf_pdf = -1.0;
    let mut samples: Vec<TrainingSample> = Vec::new();
    for set in [&a, &off, &a2, &bad, &b, &off_bin, &c] {
        samples.extend(set.iter().map(|(s, _)| *s));
    }
    // Shuffled: the fit must not depend on the samples' order.
    for k in (1..samples.len()).rev() {
        let j = rng.next_u32() as usize % (k + 1);
        samples.swap(k, j);
    }
    // MIS-weighted radiances (`mis_radiance`): what comes from well above
    // the horizon mostly goes to NEE.
    let mis_of = |s: &TrainingSample| {
        let k = if s.wi[2] > 0.5 { 0.05 } else { 1.0 };
        s.radiance.map(|l| l * k)
    };
    let mis: Vec<[f32; 3]> = samples.iter().map(mis_of).collect();
    let training = |s: &TrainingSample| s.radiance;
    let sets = [
        Some(&a[..]),
        Some(&a2[..]),
        Some(&b[..]),
        Some(&c[..]),
        None,
    ];
    let used = a.len() + a2.len() + b.len() + c.len();

    // A query in each lane (a sample's point; E's own point) and a miss (a
    // bin cell A lacks).
    let mut queries: Vec<QueryPoint> = [&a, &a2, &b, &c]
        .iter()
        .map(|s| {
            let s = &s[0].0;
            QueryPoint::new(s.position, s.normal, s.wo, s.roughness)
        })
        .collect();
    queries.push(lane_points[4]);
    queries.push(at(ca, Vec3::X, &mut rng));
    let constant = lanes.selection_probability(0);
    let mut results = Vec::new();
    for (label, radiance, given) in [
        (
            "training radiance",
            &training as &dyn Fn(&TrainingSample) -> [f32; 3],
            None,
        ),
        ("MIS radiance", &mis_of, Some(&mis[..])),
    ] {
        for prior_samples in [1, 32, 1000] {
            let fit = SelectionFit {
                prior_samples,
                ..SelectionFit::default()
            };
            assert_eq!(fit.min, 0.0);
            let (want, global) = expected_fit(&fit, &sets, radiance);
            let report = cache
                .fit_selection(&field, &samples, given, None, &fit)
                .unwrap();
            eprintln!("{label}, prior {prior_samples}: want {want:?}, global {global}: {report:?}");
            assert_eq!(report.samples_used, used as u64, "{label}");
            assert_eq!((report.cells_fitted, report.cells_global), (4, 1));
            let off = want.iter().filter(|&&c| c == 0.0).count();
            assert_eq!(report.cells_off, off as u64, "{label}");
            assert_eq!(report.global, global, "{label}");
            let (ratio, bound) = expected_variance_ratio(&fit, &sets, &want, radiance);
            eprintln!("{label}, prior {prior_samples}: variance ratio {ratio} ± {bound}");
            assert!(
                (report.variance_ratio - ratio).abs() <= bound,
                "{label}: variance ratio {} against {ratio} ± {bound}",
                report.variance_ratio
            );
            // The guide lowers the variance of these lanes (lane A's radiance
            // follows it: a variance estimate near 0, here even below).
            assert!(ratio < 1.0 && bound < 0.01, "{label}: {ratio} ± {bound}");
            let mean = want.iter().map(|&c| f64::from(c)).sum::<f64>() / 5.0;
            assert!(
                (f64::from(report.mean) - mean).abs() < 1e-6,
                "{label}: {report:?}"
            );
            // The lanes hand out the fitted values (any point of the lane's
            // cell and bin), misses the configuration's constant.
            let (got, missed) = selections(&cache, &field, &queries);
            assert_eq!(missed, vec![5]);
            assert_eq!(got[..5], want[..], "{label}, prior {prior_samples}");
            assert_eq!(got[5], constant);
            results.push((want, global));
        }
    }
    // The cases have teeth: A and B fit differently (weak prior), B inside the range
    // somewhere, the guide off (c = 0) somewhere, a lane away from both its
    // own fit and the global one (the shrinkage interpolates), the prior's
    // weight and the MIS radiance change the fit.
    let unshrunk = |k: usize| {
        let fit = SelectionFit::default();
        argmin(
            &fit,
            &moments(&fit, sets[k].unwrap(), &training),
            0.0,
            0.0,
            0.0,
        )
    };
    assert!(results.iter().any(|(w, _)| w[0] != w[2]));
    assert!(results.iter().any(|(w, _)| w[2] > 0.0 && w[2] < 0.8));
    assert!(results.iter().any(|(w, _)| w.contains(&0.0)));
    let (w32, g32) = &results[1];
    assert!(
        (0..4).any(|k| w32[k] != unshrunk(k) && w32[k] != *g32),
        "{results:?}"
    );
    assert_ne!(results[0].0, results[2].0);
    assert_ne!(results[1].0, results[4].0);
    assert!(results
        .iter()
        .any(|(w, _)| w.iter().any(|&c| c != constant)));
    // With a cost per guided vertex the fit is the argmin of variance times cost; the
    // cost has teeth: more lanes turn the guide off than without it, more still with a
    // smaller variance share, and a prohibitive cost turns every lane off.
    let fit0 = SelectionFit::default();
    let (free, _) = expected_fit(&fit0, &sets, &training);
    let mut off_by_cost = Vec::new();
    for (guide_cost, variance_share) in [(0.5, 1.0), (0.5, 0.2), (1e6, 1.0)] {
        let fit = SelectionFit {
            guide_cost,
            variance_share,
            ..fit0
        };
        let (want, global) = expected_fit(&fit, &sets, &training);
        let report = cache
            .fit_selection(&field, &samples, None, None, &fit)
            .unwrap();
        eprintln!("guide cost {guide_cost}, share {variance_share}: want {want:?}, global {global}: {report:?}");
        assert_eq!(report.global, global, "guide cost {guide_cost}");
        let (got, _) = selections(&cache, &field, &queries);
        assert_eq!(got[..5], want[..], "guide cost {guide_cost}");
        off_by_cost.push(want.iter().filter(|&&c| c == 0.0).count());
    }
    let off_free = free.iter().filter(|&&c| c == 0.0).count();
    assert!(
        off_by_cost[0] >= off_free && off_by_cost[1] > off_by_cost[0] && off_by_cost[2] > off_free,
        "{off_by_cost:?}"
    );
    for (guide_cost, variance_share) in [
        (-0.1, 1.0),
        (f32::NAN, 1.0),
        (f32::INFINITY, 1.0),
        (0.5, -0.1),
        (0.5, 1.5),
        (0.5, f32::NAN),
    ] {
        let fit = SelectionFit {
            guide_cost,
            variance_share,
            ..fit0
        };
        let r = cache.fit_selection(&field, &samples, None, None, &fit);
        assert!(matches!(r, Err(GuidingError::InvalidConfig(_))), "{r:?}");
    }
    // Back to the last fit of the loop above (results[5]) for what follows.
    let last = SelectionFit {
        prior_samples: 1000,
        ..fit0
    };
    cache
        .fit_selection(&field, &samples, Some(&mis), None, &last)
        .unwrap();
    // A lane added after the fit takes the (latest) global value.
    let d = at(centre([1, 1, 1]), Vec3::Z, &mut rng);
    assert_eq!(cache.extend(&field, &[d]).unwrap(), 1);
    let (got, missed) = selections(&cache, &field, &[d]);
    assert!(missed.is_empty());
    assert_eq!(got[0], results[5].1);
}

/// A sample without a BSDF density (`bsdf_pdf = 0`, "unknown" in
/// `TrainingSample`'s docs) makes the sum of the candidate `c = 0`
/// infinite. With `prior_samples: 0` the docs' estimator is each lane's own
/// sums (no pseudo-samples), so a lane whose own samples all have a BSDF
/// density keeps its own fit (a regression test: `fit_selection` once
/// added `0 · ∞ = NaN` to the candidate `c = 0` of every lane, after which
/// no candidate compared below it and every lane got `max`).
#[test]
fn fit_selection_without_prior_keeps_a_lane_own_fit_next_to_a_sample_without_bsdf_density() {
    let (field, mut rng, empty) = npm_with_empty_cache(180, &PRODUCT);
    let h = empty.cell_size();
    let (ca, cb) = (
        cell_centre(&empty, [2, 3, 2]),
        cell_centre(&empty, [4, 6, 4]),
    );
    let points = [at(ca, Vec3::Z, &mut rng), at(cb, Vec3::Z, &mut rng)];
    let mut cache = field.build_cache(&points, &PRODUCT).unwrap();
    let mut lanes = DistributionBatch::new();
    field.decode_batch(&points, &mut lanes);
    assert!(lanes.apply_cosine_product(&[Vec3::Z; 2]));
    let q_of = |lane: u32| lane_pdf(&field, &lanes, lane);
    let flat = |_: f32, _: Vec3| 0.5;
    let a = fit_samples(100, ca, h, Vec3::Z, &q_of(0), &flat, &mut rng);
    let mut b = fit_samples(100, cb, h, Vec3::Z, &q_of(1), &flat, &mut rng);
    b[0].0.bsdf_pdf = 0.0;
    let samples: Vec<TrainingSample> = a.iter().chain(&b).map(|(s, _)| *s).collect();
    let fit = SelectionFit {
        prior_samples: 0,
        ..SelectionFit::default()
    };
    let training = |s: &TrainingSample| s.radiance;
    let (want, _) = expected_fit(&fit, &[Some(&a[..]), Some(&b[..])], &training);
    // The BSDF fits lane A: the guide off there.
    assert_eq!(want[0], 0.0);
    cache
        .fit_selection(&field, &samples, None, None, &fit)
        .unwrap();
    let (got, _) = selections(&cache, &field, &points);
    assert_eq!(got, want);
}

/// `GuideCache::vmf_table` is the cache as its docs say: for queries looked up with the
/// jitter ½ (their own cell), the table's lane by the documented cell formula holds the
/// mixture whose density `pdf_decoded` gives for that query (to rounding); a miss is an empty
/// cell; NASG and DF caches have no vMF table.
#[test]
fn the_vmf_table_is_the_caches_lookup() {
    let mut rng = Pcg32::new(41, 7);
    for (name, config) in radiance_presets() {
        let field = trained(config, 5);
        let points: Vec<Vec3> = (0..400).map(|_| in_box(&mut rng)).collect();
        let cache = field
            .build_cache(&queries_at(&points, &mut rng), &OPTIONS)
            .unwrap();
        let Some(t) = cache.vmf_table() else {
            assert_ne!(
                name, "npm",
                "an NPM cache without the product has a vMF table"
            );
            continue;
        };
        assert_eq!(name, "npm");
        assert_eq!(t.lanes.len(), cache.cells());
        // Points of the cache (occupied cells) and random ones (mostly empty cells).
        let mut probes: Vec<Vec3> = points[..200].to_vec();
        probes.extend((0..100).map(|_| in_box(&mut rng)));
        let queries = queries_at(&probes, &mut rng);
        let jitter = vec![Vec3::splat(0.5); queries.len()];
        let (mut batch, mut missed) = (DistributionBatch::new(), Vec::new());
        cache
            .decode_batch(&field, &queries, &jitter, &mut batch, &mut missed)
            .unwrap();
        let dirs: Vec<Vec3> = (0..queries.len()).map(|_| unit(&mut rng)).collect();
        let lanes: Vec<u32> = (0..queries.len() as u32).collect();
        let mut pdfs = vec![0.0f32; queries.len()];
        field.pdf_decoded(&batch, &lanes, &dirs, &mut pdfs).unwrap();
        let mut checked = 0;
        for (i, p) in probes.iter().enumerate() {
            let c = (*p - Vec3::from_array(t.lo)) / t.cell;
            let (x, y, z) = (c.x as u32, c.y as u32, c.z as u32);
            let cell = ((z * t.res[1] + y) * t.res[0] + x) as usize;
            let lane = t.index[cell];
            assert_eq!(lane == u32::MAX, missed.contains(&(i as u32)), "query {i}");
            if lane != u32::MAX {
                // The batched kernel sums the lobes with fused multiply-adds and its own exp:
                // equal up to f32 rounding over 8 lobes (relative 1e-5).
                let pdf = t.lanes[lane as usize].pdf(dirs[i]);
                let tol = 1e-5 * pdf.abs().max(pdfs[i].abs());
                assert!(
                    (pdf - pdfs[i]).abs() <= tol,
                    "query {i}: {pdf} vs {}",
                    pdfs[i]
                );
                checked += 1;
            }
        }
        assert!(
            checked >= 200,
            "only {checked} probes fell in occupied cells"
        );
    }
}

// ---------------------------------------------------------------------------
// Queries without a surface (scattering points in media) and the lobe product.

/// With the cosine product, a query with a zero normal ("no surface") has a lane of its own
/// per cell, the network's decode without any product (bit for bit), next to the product
/// lanes of the surface normals in the same cell.
#[test]
fn queries_without_a_surface_take_a_lane_without_the_cosine_product() {
    let (field, mut rng, empty) = npm_with_empty_cache(190, &PRODUCT);
    let positions = one_position_per_cell(empty.resolution(), &mut rng);
    let surface: Vec<QueryPoint> = positions
        .iter()
        .map(|&p| at(p, fixed_unit(&mut rng), &mut rng))
        .collect();
    let medium: Vec<QueryPoint> = positions
        .iter()
        .map(|&p| at(p, Vec3::ZERO, &mut rng))
        .collect();
    let points: Vec<QueryPoint> = surface.iter().chain(&medium).copied().collect();
    let cache = field.build_cache(&points, &PRODUCT).unwrap();
    assert_eq!(cache.cells(), 2 * positions.len());
    let answer = cached_centred(&cache, &field, &medium);
    assert_all_hit_with("no surface", &medium, &answer, &network(&field, &medium));
    // The surface lanes of the same cells hold the product.
    let normals: Vec<Vec3> = surface.iter().map(|q| Vec3::from_array(q.normal)).collect();
    let answer = cached_centred(&cache, &field, &surface);
    assert_all_hit_with(
        "surface",
        &surface,
        &answer,
        &network_product(&field, &surface, &normals),
    );
    // A miss without a surface is the plain decode too.
    let far = at(
        Vec3::from_array(HI) + Vec3::splat(5.0),
        Vec3::ZERO,
        &mut rng,
    );
    let (got, lookup, missed) = cached_centred(&cache, &field, &[far]);
    assert_eq!((lookup.misses, missed), (1, vec![0]));
    assert_eq!(got, network(&field, &[far]));
}

/// `apply_lobe_product` on a batch the cache answered multiplies exactly the listed lanes
/// (as on the network's own decode, bit for bit), leaves the others and `κ = 0` lanes as
/// they were, and leaves the cache's shared cells untouched.
#[test]
fn a_lobe_product_on_a_cached_batch_copies_only_its_lanes() {
    let (field, mut rng, empty) = npm_with_empty_cache(191, &OPTIONS);
    let positions = one_position_per_cell(empty.resolution(), &mut rng);
    let queries: Vec<QueryPoint> = positions
        .iter()
        .map(|&p| at(p, Vec3::ZERO, &mut rng))
        .collect();
    let cache = field.build_cache(&queries, &OPTIONS).unwrap();
    let n = queries.len();
    // Every other lane, one listed with κ = 0.
    let lanes: Vec<u32> = (0..n as u32).step_by(2).collect();
    let axes: Vec<Vec3> = lanes.iter().map(|_| unit(&mut rng)).collect();
    let mut kappas: Vec<f32> = lanes.iter().map(|_| rng.uniform(0.3, 30.0)).collect();
    kappas[1] = 0.0;
    let mut batch = decode_centred(&cache, &field, &queries);
    assert!(batch.apply_lobe_product(&lanes, &axes, &kappas));
    let mut want = DistributionBatch::new();
    field.decode_batch(&queries, &mut want);
    let plain = fingerprints(&field, &want);
    assert!(want.apply_lobe_product(&lanes, &axes, &kappas));
    let want = fingerprints(&field, &want);
    let got = fingerprints(&field, &batch);
    let multiplied: HashSet<u32> = lanes
        .iter()
        .zip(&kappas)
        .filter(|(_, &k)| k > 0.0)
        .map(|(&l, _)| l)
        .collect();
    for i in 0..n {
        assert_eq!(got[i], want[i], "lane {i}");
        let changed = got[i] != plain[i];
        assert_eq!(changed, multiplied.contains(&(i as u32)), "lane {i}");
    }
    let (again, _, _) = cached_centred(&cache, &field, &queries);
    assert_eq!(again, plain);
    // Refused: a lane out of range, lengths that differ; nothing changes.
    let before = fingerprints(&field, &batch);
    assert!(!batch.apply_lobe_product(&[n as u32], &[Vec3::Z], &[1.0]));
    assert!(!batch.apply_lobe_product(&[0, 1], &[Vec3::Z], &[1.0]));
    assert_eq!(fingerprints(&field, &batch), before);
}

/// `fit_selection` with product lobes weighs the density the renderer samples at those
/// samples, the lane times the lobe: on samples whose radiance follows the product, the fit
/// with the lobes is the written-out argmin over the product's densities and differs from
/// the fit over the bare lane's (which the same data rates worse); lobes of another length
/// are refused.
#[test]
fn fit_selection_weighs_the_lobe_products_it_is_given() {
    let (field, mut rng, empty) = npm_with_empty_cache(192, &OPTIONS);
    let h = empty.cell_size();
    let centre = cell_centre(&empty, [3, 4, 3]);
    let point = at(centre, Vec3::ZERO, &mut rng);
    let mut cache = field.build_cache(&[point], &OPTIONS).unwrap();
    assert_eq!(cache.cells(), 1);
    // The lane and its product with a sharp lobe (κ = 40 around +x).
    let (axis, kappa) = (Vec3::X, 40.0f32);
    let mut lane = DistributionBatch::new();
    field.decode_batch(&[point], &mut lane);
    let mut product = DistributionBatch::new();
    field.decode_batch(&[point], &mut product);
    assert!(product.apply_lobe_product(&[0], &[axis], &[kappa]));
    let q_product = lane_pdf(&field, &product, 0);
    let q_bare = lane_pdf(&field, &lane, 0);
    // Medium samples (zero normal) in the cell whose radiance is the product's density:
    // the guide then matches the integrand (phase value 1/4π as `bsdf_cos` and density).
    let samples: Vec<(TrainingSample, f32)> = (0..400)
        .map(|_| {
            let off = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
            let wi = unit(&mut rng);
            let vertex = QueryPoint::from_vec3(centre + off * 0.9 * h, Vec3::ZERO, -axis, 1.0);
            let s = TrainingSample::new(
                vertex,
                wi.to_array(),
                [q_product(wi); 3],
                INV_FOUR_PI,
                INV_FOUR_PI,
                [INV_FOUR_PI; 3],
            );
            (s, q_product(wi))
        })
        .collect();
    let only: Vec<TrainingSample> = samples.iter().map(|(s, _)| *s).collect();
    let lobes = vec![
        guiding::ProductLobe {
            axis: axis.to_array(),
            kappa
        };
        only.len()
    ];
    let fit = SelectionFit::default();
    let with = cache
        .fit_selection(&field, &only, None, Some(&lobes), &fit)
        .unwrap();
    let (c_with, _) = selections(&cache, &field, &[point]);
    let m = moments(&fit, &samples, &|s| s.radiance);
    let mean = first_sum(&samples, &|s| s.radiance).powi(2) / samples.len() as f64;
    assert_eq!(c_with[0], argmin(&fit, &m, mean, 0.0, 1.0));
    assert!(
        c_with[0] > 0.5,
        "the matching product is picked: c = {}",
        c_with[0]
    );
    // The bare lane's densities: another sum, another (lower) choice.
    let bare_samples: Vec<(TrainingSample, f32)> = samples
        .iter()
        .map(|(s, _)| (*s, q_bare(Vec3::from_array(s.wi))))
        .collect();
    cache
        .fit_selection(&field, &only, None, None, &fit)
        .unwrap();
    let (c_without, _) = selections(&cache, &field, &[point]);
    let m = moments(&fit, &bare_samples, &|s| s.radiance);
    assert_eq!(c_without[0], argmin(&fit, &m, mean, 0.0, 1.0));
    assert!(
        c_without[0] < c_with[0],
        "{} vs {}",
        c_without[0],
        c_with[0]
    );
    assert!(with.variance_ratio < 1.0);
    let r = cache.fit_selection(&field, &only, None, Some(&lobes[1..]), &fit);
    assert!(
        matches!(r, Err(GuidingError::LengthMismatch { .. })),
        "{r:?}"
    );
}
