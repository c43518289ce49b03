//! Scratch driver (not committed): the batched guided vertex of micro.rs, fixed repetitions,
//! for instruction counts under callgrind.
use glam::{Vec2, Vec3};
use guiding::{FieldConfig, GuidingConfig, GuidingField, ModelSize, Representation};
use guiding_bench::inputs::{directions, queries, unit_pairs, unit_points};
use std::hint::black_box;

const N: usize = 4096;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let rep = match args[1].as_str() {
        "npm" => Representation::Npm,
        _ => Representation::Nasg,
    };
    let target = if args[2] == "radiance" { guiding::Target::Radiance } else { guiding::Target::Product };
    let reps: usize = args[3].parse().unwrap();
    let config = GuidingConfig { representation: rep, target, ..GuidingConfig::npm_radiance() }
        .with_size(ModelSize::Compact)
        .with_training(FieldConfig::DEFAULT.with_threads(1));
    let field = GuidingField::new(config, [-1.0; 3], [1.0; 3]).unwrap();
    let qs = queries(23, N);
    let us: Vec<Vec2> = unit_pairs(29, N);
    let lanes: Vec<u32> = (0..N as u32).collect();
    let lanes2: Vec<u32> = (0..2 * N as u32).map(|i| i % N as u32).collect();
    let dirs: Vec<Vec3> = directions(31, 2 * N);
    let mut batch = guiding::DistributionBatch::new();
    let mut samples = vec![guiding::DirectionSample { direction: Vec3::ZERO, pdf: 0.0 }; N];
    let mut pdfs = vec![0.0f32; 2 * N];
    let mut sel = vec![0.0f32; N];
    let cached = args.get(4).is_some_and(|a| a == "cached");
    let options = guiding::CacheOptions { cosine_product: true, ..guiding::CacheOptions::default() };
    let cache = field.build_cache(&qs, &options).unwrap();
    let jitter = unit_points(37, N);
    let mut missed = Vec::new();
    let t = std::time::Instant::now();
    for _ in 0..reps {
        if cached {
            cache.decode_batch(&field, &qs, &jitter, &mut batch, &mut missed).unwrap();
        } else {
            field.decode_batch(&qs, &mut batch);
        }
        for (i, c) in sel.iter_mut().enumerate() {
            *c = batch.selection_probability(i);
        }
        let ok = field.sample_decoded(&batch, &lanes, &us, &mut samples).is_ok()
            && field.pdf_decoded(&batch, &lanes2, &dirs, &mut pdfs).is_ok();
        black_box((ok, &samples, &pdfs, &sel));
    }
    println!("{:.1} ns/vertex", t.elapsed().as_secs_f64() * 1e9 / (reps * N) as f64);
}
