//! `guiding_core::model::mixture_batch` (eight (mixture, direction) pairs per
//! block, lane-major) against the per-lane `pdf` / `sample` of the mixtures,
//! bit for bit: every variant runs the same operations per lane in the same
//! order (Rust never contracts into FMA), so any difference is a bug, not
//! rounding. Inputs include partial blocks, repeated and unordered lanes,
//! degenerate directions (zero, NaN, ±∞, subnormal, huge) and out-of-range or
//! NaN random numbers.

use guiding_core::glam::{Vec2, Vec3};
use guiding_core::lobe::DirectionSample;
use guiding_core::mixture::nasg::{NasgMixture, NASG_RAW_PER_LOBE};
use guiding_core::mixture::vmf::{VmfMixture, VMF_RAW_PER_LOBE};
use guiding_core::mixture::LobeMixture;
use guiding_core::model::batched::DfTable;
use guiding_core::model::mixture_batch as mb;
use guiding_core::pdf1d::Interpolation;
use guiding_core::sphere::square_to_uniform_sphere;
use guiding_tests::rng::Pcg32;

const SPECIAL_RAW: [f32; 8] = [
    0.0,
    f32::NAN,
    f32::INFINITY,
    -f32::INFINITY,
    1e30,
    -1e30,
    40.0,
    -40.0,
];

fn raw_value(rng: &mut Pcg32) -> f32 {
    if rng.next_f32() < 0.05 {
        SPECIAL_RAW[rng.next_u32() as usize % SPECIAL_RAW.len()]
    } else {
        rng.uniform(-6.0, 6.0)
    }
}

fn nasg_mixtures(n: usize, rng: &mut Pcg32) -> Vec<NasgMixture<8>> {
    (0..n)
        .map(|_| {
            let raw: [[f32; NASG_RAW_PER_LOBE]; 8] =
                std::array::from_fn(|_| std::array::from_fn(|_| raw_value(rng)));
            NasgMixture::decode(&raw, raw_value(rng))
        })
        .collect()
}

fn vmf_mixtures(n: usize, rng: &mut Pcg32) -> Vec<VmfMixture<8>> {
    (0..n)
        .map(|_| {
            let raw: [[f32; VMF_RAW_PER_LOBE]; 8] =
                std::array::from_fn(|_| std::array::from_fn(|_| raw_value(rng)));
            VmfMixture::decode(&raw)
        })
        .collect()
}

/// Unit directions, scaled ones and every degenerate kind.
fn direction(rng: &mut Pcg32) -> Vec3 {
    let d = square_to_uniform_sphere(rng.next_vec2());
    match rng.next_u32() % 16 {
        0 => Vec3::ZERO,
        1 => Vec3::new(f32::NAN, 0.0, 1.0),
        2 => Vec3::new(f32::INFINITY, 1.0, 0.0),
        3 => d * 1e-41,
        4 => d * 3e19,
        5 => d * 2.5,
        _ => d,
    }
}

fn random_u(rng: &mut Pcg32) -> Vec2 {
    match rng.next_u32() % 12 {
        0 => Vec2::new(0.0, 0.0),
        1 => Vec2::new(1.0 - f32::EPSILON / 2.0, 1.0 - f32::EPSILON / 2.0),
        2 => Vec2::new(f32::NAN, -0.5),
        3 => Vec2::new(1.5, f32::NAN),
        _ => rng.next_vec2(),
    }
}

struct Case {
    lanes: Vec<u32>,
    dirs: Vec<Vec3>,
    us: Vec<Vec2>,
}

fn case(n: usize, mixtures: usize, rng: &mut Pcg32) -> Case {
    Case {
        lanes: (0..n).map(|_| rng.next_u32() % mixtures as u32).collect(),
        dirs: (0..n).map(|_| direction(rng)).collect(),
        us: (0..n).map(|_| random_u(rng)).collect(),
    }
}

type PdfFn<M> = fn(&[M], &[u32], &[Vec3], &mut [f32]);
type SampleFn<M> = fn(&[M], &[u32], &[Vec2], &mut [DirectionSample]);

/// `(name, pdf kernel, sample kernel)` of each variant.
type Variants<M> = Vec<(&'static str, PdfFn<M>, SampleFn<M>)>;

/// The dispatched entry, the baseline body and, where the CPU has them, the
/// AVX2 and AVX-512F copies of a family's pdf and sample kernels (a macro:
/// the copies are distinct `unsafe` functions).
macro_rules! variants {
    ($mb:ident: $pdf:ident, $sample:ident; $pdf_p:ident, $sample_p:ident;
        $pdf_2:ident, $sample_2:ident; $pdf_5:ident, $sample_5:ident) => {{
        let mut v: Variants<_> = vec![
            ("dispatched", $mb::$pdf, $mb::$sample),
            ("portable", $mb::$pdf_p, $mb::$sample_p),
        ];
        #[cfg(target_arch = "x86_64")]
        {
            if std::is_x86_feature_detected!("avx2") {
                // SAFETY: AVX2 support was just checked.
                v.push((
                    "avx2",
                    |m, l, d, o| unsafe { $mb::$pdf_2(m, l, d, o) },
                    |m, l, u, o| unsafe { $mb::$sample_2(m, l, u, o) },
                ));
            }
            if std::is_x86_feature_detected!("avx512f") && std::is_x86_feature_detected!("avx2") {
                // SAFETY: AVX-512F and AVX2 support was just checked.
                v.push((
                    "avx512",
                    |m, l, d, o| unsafe { $mb::$pdf_5(m, l, d, o) },
                    |m, l, u, o| unsafe { $mb::$sample_5(m, l, u, o) },
                ));
            }
        }
        v
    }};
}

fn nasg_variants() -> Variants<NasgMixture<8>> {
    variants!(mb: nasg_pdf_batch, nasg_sample_batch; nasg_pdf_portable, nasg_sample_portable;
        nasg_pdf_avx2, nasg_sample_avx2; nasg_pdf_avx512, nasg_sample_avx512)
}

fn vmf_variants() -> Variants<VmfMixture<8>> {
    variants!(mb: vmf_pdf_batch, vmf_sample_batch; vmf_pdf_portable, vmf_sample_portable;
        vmf_pdf_avx2, vmf_sample_avx2; vmf_pdf_avx512, vmf_sample_avx512)
}

fn sample_bits(s: &DirectionSample) -> [u32; 4] {
    [
        s.direction.x.to_bits(),
        s.direction.y.to_bits(),
        s.direction.z.to_bits(),
        s.pdf.to_bits(),
    ]
}

const EMPTY: DirectionSample = DirectionSample {
    direction: Vec3::ZERO,
    pdf: 0.0,
};

/// Every variant against the per-lane reference (the mixture's own `pdf` and
/// `sample`) on batches of every length kind (empty, partial blocks, one
/// block, several).
fn check_variants<M: LobeMixture>(
    mixtures: &[M],
    variants: Vec<(&'static str, PdfFn<M>, SampleFn<M>)>,
    rng: &mut Pcg32,
) {
    for n in [0, 1, 7, 8, 9, 63, 1000] {
        let c = case(n, mixtures.len(), rng);
        for (name, pdf_batch, sample_batch) in &variants {
            let mut out = vec![-1.0f32; n];
            pdf_batch(mixtures, &c.lanes, &c.dirs, &mut out);
            let mut samples = vec![EMPTY; n];
            sample_batch(mixtures, &c.lanes, &c.us, &mut samples);
            for i in 0..n {
                let m = &mixtures[c.lanes[i] as usize];
                let want = m.pdf(c.dirs[i]);
                assert_eq!(
                    out[i].to_bits(),
                    want.to_bits(),
                    "{name} n {n} lane {i}: {} vs {want}",
                    out[i]
                );
                let s = m.sample(c.us[i]);
                assert_eq!(
                    sample_bits(&samples[i]),
                    sample_bits(&s),
                    "{name} n {n} sample {i}"
                );
            }
        }
    }
}

#[test]
fn batched_nasg_densities_and_samples_are_the_per_lane_ones_bit_for_bit() {
    let mut rng = Pcg32::new(41, 5);
    let mixtures = nasg_mixtures(37, &mut rng);
    check_variants(&mixtures, nasg_variants(), &mut rng);
}

#[test]
fn batched_vmf_densities_and_samples_are_the_per_lane_ones_bit_for_bit() {
    let mut rng = Pcg32::new(43, 5);
    let mixtures = vmf_mixtures(37, &mut rng);
    check_variants(&mixtures, vmf_variants(), &mut rng);
}

#[test]
#[should_panic(expected = "lanes")]
fn a_length_mismatch_panics_with_the_lengths() {
    let mut rng = Pcg32::new(53, 5);
    let mixtures = vmf_mixtures(2, &mut rng);
    let mut out = vec![0.0f32; 2];
    mb::vmf_pdf_batch(&mixtures, &[0, 1, 1], &[Vec3::Z; 3], &mut out);
}

/// Tables with smooth, spiky and one-hot logits, both interpolations.
fn tables(n: usize, rng: &mut Pcg32) -> Vec<DfTable> {
    (0..n)
        .map(|i| {
            let scale = [1.0, 8.0, 40.0][i % 3];
            let marginal: [f32; 32] = std::array::from_fn(|_| scale * rng.uniform(-1.0, 1.0));
            let conditional: [[f32; 16]; 32] =
                std::array::from_fn(|_| std::array::from_fn(|_| scale * rng.uniform(-1.0, 1.0)));
            let interpolation = if i % 2 == 0 {
                Interpolation::Linear
            } else {
                Interpolation::Nearest
            };
            DfTable::from_logits(&marginal, &conditional, interpolation)
        })
        .collect()
}

#[test]
fn batched_table_densities_and_samples_are_the_per_lane_ones_bit_for_bit() {
    let mut rng = Pcg32::new(59, 5);
    let tables = tables(23, &mut rng);
    let sums: Vec<_> = tables.iter().map(DfTable::running_sums).collect();
    for n in [0, 1, 7, 8, 9, 100, 1000] {
        let c = case(n, tables.len(), &mut rng);
        let mut out = vec![-1.0f32; n];
        mb::table_pdf_batch(&tables, &c.lanes, &c.dirs, &mut out);
        let mut samples = vec![EMPTY; n];
        mb::table_sample_batch(&tables, &sums, &c.lanes, &c.us, &mut samples);
        for i in 0..n {
            let t = &tables[c.lanes[i] as usize];
            assert_eq!(
                out[i].to_bits(),
                t.pdf(c.dirs[i]).to_bits(),
                "n {n} lane {i}"
            );
            assert_eq!(
                sample_bits(&samples[i]),
                sample_bits(&t.sample(c.us[i])),
                "n {n} sample {i}"
            );
        }
    }
}
