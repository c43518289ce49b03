//! Replays the fuzz corpora on stable: every file under `fuzz/corpus/<target>/`
//! (including every crash ever found, minimised) plus a deterministic set of
//! generated inputs, through the same checks the cargo-fuzz targets run.
//!
//! `write_seed_corpora` (ignored) writes the hand-made seeds of
//! `training_step` and `scene_parser`; see `fuzz/README.md`.

use glam::Vec3;
use guiding_core::lobe::vmf::VmfLobe;
use guiding_core::math::INV_FOUR_PI;
use guiding_core::model::QueryPoint;
use guiding_core::sample::TrainingSample;
use guiding_core::sphere::square_to_uniform_sphere;
use guiding_tests::fuzz_checks::{self, scene_input, TrainingInput, SCENE_INPUT_LIMIT};
use guiding_tests::rng::Pcg32;
use std::path::PathBuf;

fn corpus_dir(target: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/corpus")
        .join(target)
}

fn corpus_files(target: &str) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(corpus_dir(target))
        .map(|entries| entries.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    files.sort();
    files
}

fn corpus(target: &str) -> Vec<Vec<u8>> {
    corpus_files(target)
        .iter()
        .map(|p| std::fs::read(p).unwrap())
        .collect()
}

/// Special f32 bit patterns that sit at the edges of every domain.
const SPECIAL: [f32; 16] = fuzz_checks::special_values(
    [0.0, -0.0, 1e-45, -1e-45, 1e-38, 1e-30, 1e-4, 1.0, -1.0, 1e4],
    [],
);

/// Deterministic inputs: random bytes, and byte strings built from special
/// floats, so the replay covers the extremes even before a fuzzer ran.
fn generated_inputs(seed: u64, count: usize, max_len: usize) -> Vec<Vec<u8>> {
    let mut rng = Pcg32::new(seed, 7);
    (0..count)
        .map(|i| {
            let len = 1 + (rng.next_u32() as usize % max_len);
            let mut bytes = vec![(rng.next_u32() & 0xff) as u8];
            while bytes.len() < len {
                let word = if i % 2 == 0 {
                    rng.next_u32()
                } else if rng.next_u32() % 4 == 0 {
                    // Keep some sample-point/selector bytes random.
                    rng.next_u32()
                } else {
                    SPECIAL[rng.next_u32() as usize % SPECIAL.len()].to_bits()
                };
                bytes.extend_from_slice(&word.to_le_bytes());
            }
            bytes
        })
        .collect()
}

/// Tokens that stress the scene loaders where numbers and names go.
const SCENE_TOKENS: [&str; 16] = [
    "nan",
    "inf",
    "-inf",
    "1e39",
    "-1e39",
    "3.4e38",
    "-0",
    "0",
    "1e-45",
    "-1",
    "-9223372036854775808",
    "4294967296",
    "\"",
    "<",
    "/>",
    "\0",
];

/// Deterministic mutations of the seed scenes (a tiny mutational fuzzer for
/// stable): numbers replaced by special tokens, ranges deleted, duplicated
/// or truncated, bytes overwritten.
fn mutated_scenes(seeds: &[Vec<u8>], count: usize) -> Vec<Vec<u8>> {
    let mut rng = Pcg32::new(0x5ce7e, 11);
    let mut below = |n: usize| rng.next_u32() as usize % n.max(1);
    (0..count)
        .map(|_| {
            let mut s = seeds[below(seeds.len())].clone();
            for _ in 0..1 + below(4) {
                let len = s.len();
                let (a, b) = {
                    let a = below(len + 1);
                    (a, (a + below(64)).min(len))
                };
                match below(6) {
                    0 | 1 => {
                        // Replace the number starting at or after `a`.
                        let start = s[a..]
                            .iter()
                            .position(u8::is_ascii_digit)
                            .map_or(len, |p| a + p);
                        let end = s[start..]
                            .iter()
                            .position(|c| !(c.is_ascii_digit() || b".e-+".contains(c)))
                            .map_or(len, |p| start + p);
                        let tok = SCENE_TOKENS[below(SCENE_TOKENS.len())].as_bytes();
                        s.splice(start..end, tok.iter().copied());
                    }
                    2 => {
                        s.drain(a..b);
                    }
                    3 => {
                        let piece = s[a..b].to_vec();
                        s.splice(b..b, piece);
                    }
                    4 => s.truncate(a),
                    _ => {
                        if a < len {
                            s[a] = (below(256)) as u8;
                        }
                    }
                }
            }
            s.truncate(SCENE_INPUT_LIMIT);
            s
        })
        .collect()
}

/// [`replay`] with `count` [`generated_inputs`] of at most `max_len` bytes,
/// seeded by the length of the target's name.
fn replay_generated(target: &str, check: fn(&[u8]), count: usize, max_len: usize) {
    replay(
        target,
        check,
        &generated_inputs(target.len() as u64, count, max_len),
    );
}

fn replay(target: &str, check: fn(&[u8]), generated: &[Vec<u8>]) {
    let files = corpus_files(target);
    assert!(!files.is_empty(), "{target}: empty corpus");
    for path in &files {
        let data = std::fs::read(path).unwrap();
        let result = std::panic::catch_unwind(|| check(&data));
        assert!(
            result.is_ok(),
            "{target}: corpus input {} fails",
            path.display()
        );
    }
    for (i, data) in generated.iter().enumerate() {
        let result = std::panic::catch_unwind(|| check(data));
        assert!(
            result.is_ok(),
            "{target}: generated input {i} fails: {data:?}"
        );
    }
    println!(
        "{target}: {} corpus files and {} generated inputs replayed",
        files.len(),
        generated.len()
    );
}

/// Every representation from arbitrary raw outputs. Factorised one-hot
/// tables sampled at exact bin edges and poles (u = 0, 1 − 2⁻²⁴, forced by
/// the inputs) used to fail here (~12 % of the generated inputs): the sampled
/// direction came back from the warp in a zero-density neighbour bin. Fixed
/// by keeping sampled points `SAMPLE_MARGIN` inside their cell
/// (`guiding_core::factorised`).
#[test]
fn distributions_corpus() {
    // DF tables read 1 + (32 + 32·16)·4 + … bytes; go a little beyond.
    replay_generated("distributions", fuzz_checks::distributions, 20_000, 2400);
}

#[test]
fn lobes_extreme_corpus() {
    replay_generated("lobes_extreme", fuzz_checks::lobes_extreme, 20_000, 80);
}

#[test]
fn training_step_corpus() {
    // Three rounds of 24 samples read up to ~11 kB; most generated inputs
    // stop after a few samples, which is where the decoding is densest.
    replay_generated(
        "training_step",
        |d| {
            fuzz_checks::training_step(d);
        },
        1500,
        3000,
    );
}

#[test]
fn scene_parser_corpus() {
    let mut generated = mutated_scenes(&corpus("scene_parser"), 3000);
    generated.extend(generated_inputs("scene_parser".len() as u64, 500, 400));
    replay("scene_parser", fuzz_checks::scene_parser, &generated);
}

/// Call sequences on the C ABI: the seeds plus random and special-float
/// byte strings (each at most `C_API_MAX_OPS` calls on Small models).
#[test]
fn c_api_corpus() {
    replay_generated("c_api", fuzz_checks::c_api, 1500, 400);
}

/// The hand-made seeds of `c_api` are the ones `write_seed_corpora` writes.
#[test]
fn c_api_seeds_are_checked_in() {
    for (name, bytes) in c_api_seeds() {
        let path = corpus_dir("c_api").join(&name);
        assert_eq!(
            std::fs::read(&path).ok(),
            Some(bytes),
            "{name}: run write_seed_corpora"
        );
    }
}

/// Every `[[bin]]` of `fuzz/Cargo.toml` has a non-empty corpus and a replay
/// test `<name>_corpus` in this file (so a new target, e.g. `c_api`, cannot
/// land without its stable replay).
#[test]
fn every_target_is_replayed() {
    let manifest = include_str!("../../fuzz/Cargo.toml");
    let this_file = include_str!("fuzz_corpus.rs");
    let names: Vec<&str> = manifest
        .split("[[bin]]")
        .skip(1)
        .filter_map(|bin| {
            bin.lines()
                .find_map(|l| l.trim().strip_prefix("name = "))
                .map(|n| n.trim_matches('"'))
        })
        .collect();
    assert!(names.len() >= 4, "{names:?}");
    for name in names {
        assert!(
            this_file.contains(&format!("fn {name}_corpus()")),
            "fuzz target {name} has no replay test"
        );
        assert!(!corpus_files(name).is_empty(), "{name}: empty corpus");
    }
}

// ---------------------------------------------------------------------------
// Seeds.

/// Bytes of a `c_api` call sequence (see `guiding_tests::fuzz_checks::c_api`
/// for how each call reads them).
#[derive(Default)]
struct Calls(Vec<u8>);

impl Calls {
    fn bytes(mut self, b: &[u8]) -> Self {
        self.0.extend_from_slice(b);
        self
    }
    /// A value read as a plausible number in [0, 1) (`c_value`).
    fn unit(self, x: f32) -> Self {
        let bits = ((x * 16_777_216.0) as u32) << 8;
        self.bytes(&[3]).bytes(&bits.to_le_bytes())
    }
    /// A unit direction from two numbers in [0, 1) (`c_dir3`).
    fn dir(self, u: f32, v: f32) -> Self {
        let (a, b) = (
            ((u * 16_777_216.0) as u32) << 8,
            ((v * 16_777_216.0) as u32) << 8,
        );
        self.bytes(&[2])
            .bytes(&a.to_le_bytes())
            .bytes(&b.to_le_bytes())
    }
    fn position(self, p: [f32; 3]) -> Self {
        let mut c = self.bytes(&[1]);
        for x in p {
            c = c.bytes(&((((x + 1.0) / 2.0 * 16_777_216.0) as u32) << 8).to_le_bytes());
        }
        c
    }
    /// A valid Small field of representation `rep` in slot `slot`.
    fn new_field(self, slot: u8, rep: u8, product: bool) -> Self {
        // flags 0x14: default training values and bounds [-1, 1]³;
        // 1 thread, batch 16, 4 steps, 64 buffered, seed 0; out not NULL.
        self.bytes(&[slot << 7, rep, 0x14, u8::from(product), 0, 15, 3, 63, 0, 1])
    }
    fn new_dist(self, slot: u8) -> Self {
        self.bytes(&[(slot << 7) | 18, 0])
    }
    /// The shading point `t` of a query or training sample (`c_query`,
    /// `c_sample`): position `(t − ½, ¼, −t)`, roughness ½, the normal
    /// from (0.1, 0.2).
    fn shading_point(self, t: f32) -> Self {
        self.position([t - 0.5, 0.25, -t]).unit(0.5).dir(0.1, 0.2)
    }
    fn query(mut self, slot: u8, n: u8) -> Self {
        self = self.bytes(&[(slot << 7) | 3, n]);
        for i in 0..n {
            let t = f32::from(i) / 8.0;
            self = self.shading_point(t).dir(0.3 + t, 0.7);
        }
        self.bytes(&[1])
    }
    fn dist_sample(mut self, slot: u8, n: u8) -> Self {
        self = self.bytes(&[(slot << 7) | 5, n, 1]);
        for i in 0..2 * u32::from(n) {
            self = self.bytes(&((i * 0x1357_9bdf) | 0xff).to_le_bytes());
        }
        self.bytes(&[1])
    }
    fn dist_pdf(mut self, slot: u8, n: u8) -> Self {
        self = self.bytes(&[(slot << 7) | 6, n]);
        for i in 0..n {
            self = self.dir(f32::from(i) / 8.0, 0.3);
        }
        self
    }
    fn add_samples(mut self, slot: u8, n: u8) -> Self {
        self = self.bytes(&[(slot << 7) | 11, n]);
        for i in 0..n {
            let t = f32::from(i) / 8.0;
            self = self
                .shading_point(t)
                .unit(0.08)
                .dir(0.3, 0.7)
                .unit(0.05)
                .dir(t, 0.4)
                .unit(t)
                .unit(t)
                .unit(0.5)
                .unit(0.2)
                .unit(0.2)
                .unit(0.2);
        }
        self.bytes(&[1])
    }
    fn update(self, slot: u8) -> Self {
        self.bytes(&[(slot << 7) | 13, 0])
    }
    fn op(self, slot: u8, op: u8) -> Self {
        self.bytes(&[(slot << 7) | op])
    }
}

fn c_api_seeds() -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    for (rep, name) in ["npm", "nasg", "dfn", "dfl"].iter().enumerate() {
        let rep = rep as u8;
        let product = rep % 2 == 1;
        // Train, query, sample and evaluate; n beyond what is held.
        let train = Calls::default()
            .new_field(0, rep, product)
            .new_dist(0)
            .add_samples(0, 8)
            .update(0)
            .query(0, 4)
            .dist_sample(0, 4)
            .dist_pdf(0, 4)
            .bytes(&[7, 4])
            .dist_sample(0, 7)
            .add_samples(0, 8)
            .update(0)
            // Stale after the update.
            .dist_sample(0, 2)
            .op(0, 14);
        out.push((format!("seed-{name}-train-query"), train.0));
    }
    // Save and load, intact and with a flipped byte.
    let save = Calls::default()
        .new_field(1, 0, false)
        .add_samples(1, 4)
        .update(1)
        .bytes(&[0x80 | 17, 0])
        .op(1, 14)
        .bytes(&[0x80 | 17, 1])
        .bytes(&40u32.to_le_bytes())
        .bytes(&[2, 0x10]);
    out.push(("seed-save-load".into(), save.0));
    // Distributions outliving their field; release and NULL sweep.
    let outlive = Calls::default()
        .new_field(0, 1, false)
        .new_dist(0)
        .query(0, 3)
        .op(0, 2)
        .dist_sample(0, 3)
        .dist_pdf(0, 3)
        .op(0, 19);
    out.push(("seed-dist-outlives-field".into(), outlive.0));
    // A recorder: new, start, two vertices, end, count, flush.
    let rec = Calls::default()
        .new_field(0, 2, false)
        .bytes(&[16, 0, 0])
        .bytes(&[16, 1]);
    let mut rec = rec;
    for _ in 0..2 {
        rec = rec
            .bytes(&[16, 2])
            .position([0.1, 0.2, 0.3])
            .dir(0.5, 0.5)
            .dir(0.2, 0.1)
            .dir(0.7, 0.3)
            .unit(0.1)
            .unit(0.5)
            .unit(0.5)
            .bytes(&[0])
            .unit(0.2)
            .unit(0.2)
            .unit(0.3)
            .unit(0.3)
            .unit(0.3);
    }
    let rec = rec.bytes(&[16, 5, 1, 16, 6, 1, 16, 7]).update(0);
    out.push(("seed-recorder".into(), rec.0));
    // A scheduled loop: an spp budget of 8 with the epoch rule (2 epochs,
    // train fraction 0.5), the phase, a piece, samples, the traced time, the
    // scheduled update and the report; then the end of training, an update
    // that runs nothing, and the NULL sweep.
    let sched = Calls::default()
        .new_field(0, 0, false)
        .bytes(&[19, 0, 3, 8])
        .bytes(&((((0.5 * 16_777_216.0) as u32) << 8).to_le_bytes()))
        .bytes(&[1, 3, 1])
        .bytes(&[19, 3])
        .unit(0.1)
        .bytes(&[0, 1])
        .bytes(&[19, 6])
        .bytes(&8u32.to_le_bytes())
        .bytes(&[0, 1])
        .add_samples(0, 8)
        .bytes(&[19, 5])
        .unit(0.01)
        .bytes(&8u32.to_le_bytes())
        .bytes(&[20, 1, 19, 7, 19, 4])
        .add_samples(0, 4)
        .bytes(&[20, 1, 21]);
    out.push(("seed-schedule".into(), sched.0));
    // Efficiency trials on 6 x 6 pixels: a guide trial whose guided passes have 49 times the
    // variance of the unguided ones (alternating, guided first) up to its verdict, a pass
    // after it (refused), the verdict getters; a window trial in its ABBA order with the
    // window's passes the precise ones; the verdict rules on an arbitrary verdict.
    let mut trials = Calls::default().bytes(&[24, 0, 6, 6, 1, 2, 3, 4, 0, 0]);
    for pass in 0..6u8 {
        let sd = if pass % 2 == 0 { 7 } else { 1 };
        trials = trials.bytes(&[24, 3, 0, sd, pass, 0, 0, 1]);
    }
    trials = trials
        .bytes(&[24, 6, 2])
        .bytes(&[24, 1, 6, 6, 5, 6, 7, 8, 0, 0]);
    for (pass, with_window) in [true, false, false, true, true, false].iter().enumerate() {
        let sd = if *with_window { 1 } else { 7 };
        trials = trials.bytes(&[24, 4, 0, sd, pass as u8, 0, 0, 1]);
    }
    trials = trials.bytes(&[24, 7, 1, 1]).unit(0.4).unit(0.9);
    out.push(("seed-trials".into(), trials.0));
    out
}

/// A valid radiance-target sample at `p` towards `wi` (vMF κ = 20 radiance).
fn valid_sample(rng: &mut Pcg32, product: bool) -> TrainingSample {
    let p = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - Vec3::ONE;
    let wi = square_to_uniform_sphere(rng.next_vec2());
    let l = VmfLobe::new(Vec3::new(0.3, 0.9, 0.3).normalize(), 20.0).pdf(wi);
    let (normal, wo, bsdf_cos) = if product {
        ([0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.3 * wi.z.abs(); 3])
    } else {
        ([0.0; 3], [0.0; 3], [0.0; 3])
    };
    TrainingSample::new(
        QueryPoint::new(p.to_array(), normal, wo, 0.5),
        wi.to_array(),
        [l; 3],
        INV_FOUR_PI,
        if product { INV_FOUR_PI } else { 0.0 },
        bsdf_cos,
    )
}

/// One sample per rejection kind, and valid extremes (−0 radiance, 10⁶
/// and 10³⁰ radiance, a subnormal sample pdf, directions 10⁻⁴ off unit).
fn edge_samples(rng: &mut Pcg32, product: bool) -> Vec<TrainingSample> {
    let mut out = Vec::new();
    let edits: [fn(&mut TrainingSample); 12] = [
        |s| s.radiance[1] = f32::NAN,
        |s| s.position[0] = f32::INFINITY,
        |s| s.bsdf_pdf = f32::NEG_INFINITY,
        |s| s.radiance[0] = -1.0,
        |s| s.bsdf_cos[2] = -1e-45,
        |s| s.sample_pdf = 0.0,
        |s| s.sample_pdf = -0.0,
        |s| s.wi = [0.0; 3],
        |s| s.radiance = [-0.0; 3],
        |s| s.radiance = s.radiance.map(|l| l * 1e6 + 1e3),
        |s| s.radiance = [1e30; 3],
        |s| s.sample_pdf = 1e-45,
    ];
    for edit in edits {
        let mut s = valid_sample(rng, product);
        edit(&mut s);
        out.push(s);
    }
    let mut s = valid_sample(rng, product);
    s.wi = s.wi.map(|x| x * (1.0 + 9e-4));
    out.push(s);
    out
}

fn default_query(rng: &mut Pcg32) -> QueryPoint {
    QueryPoint::new(
        [rng.next_f32(), rng.next_f32(), rng.next_f32()],
        [0.0, 0.0, 1.0],
        [0.6, 0.0, 0.8],
        0.5,
    )
}

fn training_seeds() -> Vec<(String, Vec<u8>)> {
    const NAMES: [&str; 8] = [
        "npm-radiance",
        "npm-product",
        "nasg-radiance",
        "nasg-product",
        "dfn-radiance",
        "dfn-product",
        "dfl-radiance",
        "dfl-product",
    ];
    // lr 1e-2, EMA 0.95 | batch 8, 4 steps, 2 chunks | capacity 32, clip 1e18.
    let config = [2 | (2 << 3), 7 | (3 << 3) | (1 << 5), 31];
    let mut out = Vec::new();
    for (head, name) in NAMES.iter().enumerate() {
        let product = head % 2 == 1;
        let mut rng = Pcg32::new(head as u64, 5);
        let valid: Vec<_> = (0..24).map(|_| valid_sample(&mut rng, product)).collect();
        let edges = edge_samples(&mut rng, product);
        let q = default_query(&mut rng);
        let d = Vec3::new(0.0, 0.0, -1.0);
        let seeds = [
            ("valid", config, 4u8, vec![&valid[..], &valid[8..]]),
            ("edges", config, 4, vec![&edges[..], &valid[..4]]),
            // Capacity 1: every valid sample after the first overflows.
            ("overflow", [config[0], config[1], 0], 4, vec![&valid[..]]),
            ("params-1e30", config, 3, vec![&valid[..12]]),
            ("params-1e-30", config, 0, vec![&valid[..12]]),
            // Learning rate 1e30, clip 1e-30.
            (
                "lr-1e30",
                [7, config[1], 31 | (2 << 5)],
                4,
                vec![&edges[..]],
            ),
        ];
        for (kind, config, scale, rounds) in seeds {
            let mut input =
                TrainingInput::new(head as u8, config, scale).rounds(rounds.len() as u8);
            for r in &rounds {
                input = input.round(r);
            }
            let input = input
                .query(&q, [0, (1 << 24) - 1], d)
                .query(&q, [1 << 23, 1 << 22], Vec3::Z)
                .finish();
            out.push((format!("seed-{name}-{kind}"), input));
        }
    }
    out
}

/// The scene input of shared scene `name` (`shared/scenes/` beside the repository, i.e.
/// `../shared/scenes` from its root; CI always has it). A missing scene fails the test with
/// the path it expected instead of silently dropping the seed.
fn shared_scene(name: &str) -> Vec<u8> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/scenes")
        .join(name);
    let path = dir.join("scene.xml");
    let xml = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "shared scene not found: expected {} (the `shared/scenes` folder beside the \
             repository, i.e. ../shared/scenes from its root): {e}",
            path.display()
        )
    });
    let mut meshes = Vec::new();
    for i in 0..16 {
        let name = format!("meshes/mesh{i:02}.obj");
        if let Ok(text) = std::fs::read_to_string(dir.join(&name)) {
            meshes.push((name, text));
        }
    }
    let refs: Vec<(&str, &str)> = meshes
        .iter()
        .map(|(n, t)| (n.as_str(), t.as_str()))
        .collect();
    scene_input(&xml, &refs)
}

const SENSOR: &str = r#"<sensor type="perspective"><float name="fov" value="40"/>
<transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
<film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="24"/></film></sensor>"#;

const QUAD_OBJ: &str = "# quad\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvn 0 0 1\n\
                        o q\ng g\ns off\nusemtl m\nf 1/1/1 2/1/1 3/1/1 4/1/1\nf -4//1 -2//1 -1//1\n";

/// Named mesh texts of a scene input.
type Meshes<'a> = &'a [(&'a str, &'a str)];

fn scene_seeds() -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    for name in ["cornell-box", "veach-mis"] {
        out.push((format!("seed-shared-{name}"), shared_scene(name)));
    }
    let xml = |body: &str| format!("<scene version=\"3.0.0\">\n{SENSOR}\n{body}\n</scene>\n");
    let hand: [(&str, String, Meshes); 12] = [
        (
            "sphere-light",
            xml(r#"<integrator type="path"><integer name="max_depth" value="4"/></integrator>
<shape type="sphere"><point name="center" x="0" y="0" z="0"/><float name="radius" value="1"/>
<bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></shape>
<shape type="rectangle"><transform name="to_world"><scale value="0.5"/><rotate x="1" angle="90"/><translate y="2"/></transform>
<boolean name="flip_normals" value="true"/><emitter type="area"><rgb name="radiance" value="10, 10, 10"/></emitter></shape>"#),
            &[],
        ),
        (
            "conductor-obj",
            xml(r#"<bsdf type="roughconductor" id="c"><string name="distribution" value="ggx"/>
<float name="alpha" value="0.2"/><rgb name="eta" value="0.2, 0.9, 1.1"/><rgb name="k" value="3.9, 2.4, 2.1"/><boolean name="sample_visible" value="true"/></bsdf>
<bsdf type="roughconductor" id="none"><string name="distribution" value="ggx"/><string name="material" value="none"/></bsdf>
<shape type="obj"><string name="filename" value="quad.obj"/><ref id="c"/><boolean name="face_normals" value="true"/>
<transform name="to_world"><matrix value="1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1"/></transform></shape>
<shape type="obj"><string name="filename" value="quad.obj"/><ref id="none"/>
<transform name="to_world"><matrix value="0 0 1 0 1 0 1 0 0"/></transform></shape>"#),
            &[("quad.obj", QUAD_OBJ)],
        ),
        (
            "sampler-film",
            r#"<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="30"/><string name="fov_axis" value="larger"/>
<float name="near_clip" value="0.01"/><float name="far_clip" value="100"/>
<sampler type="independent"><integer name="sample_count" value="16"/><integer name="seed" value="3"/></sampler>
<film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="16"/><rfilter type="box"/></film></sensor>
<shape type="obj"><string name="filename" value="a.obj"/></shape></scene>"#
                .to_string(),
            &[("a.obj", "v 0 0 1\nv 1 0 1\nv 0 1 1\nf 1 2 3\n")],
        ),
        ("missing-mesh", xml(r#"<shape type="obj"><string name="filename" value="nowhere.obj"/></shape>"#), &[]),
        ("unknown-plugin", xml(r#"<bsdf type="plastic" id="p"/>"#), &[]),
        ("no-sensor", "<scene><shape type=\"sphere\"/></scene>".to_string(), &[]),
        ("nan-values", xml(r#"<shape type="sphere"><float name="radius" value="nan"/></shape>
<shape type="rectangle"><emitter type="area"><rgb name="radiance" value="inf, 1, -1"/></emitter></shape>"#), &[]),
        ("entity", "<!DOCTYPE s [<!ENTITY a \"aaaaaaaaaa\"><!ENTITY b \"&a;&a;&a;&a;\">]><scene>&b;</scene>".to_string(), &[]),
        ("bad-transform", xml(r#"<shape type="rectangle"><transform name="to_world"><rotate value="0" angle="10"/><lookat origin="1,1,1" target="1,1,1"/></transform></shape>"#), &[]),
        ("bad-obj", xml(r#"<shape type="obj"><string name="filename" value="b.obj"/></shape>"#),
            &[("b.obj", "v 0 0 0\nv 1 0 0\nf 1 2 3\nf 0 1 2\nvn 1 2\ncurv 1\n")]),
        ("deep", format!("<scene>{}{}</scene>", "<a>".repeat(200), "</a>".repeat(200)), &[]),
        ("huge-coords", xml(r#"<shape type="obj"><string name="filename" value="h.obj"/></shape>"#),
            &[("h.obj", "v -3e38 -3e38 0\nv 3e38 -3e38 0\nv 0 3e38 0\nf 1 2 3\n")]),
    ];
    for (name, xml, meshes) in hand {
        out.push((format!("seed-{name}"), scene_input(&xml, meshes)));
    }
    // Pure OBJ inputs (no NUL: parsed as OBJ and as XML).
    out.push(("seed-obj-quad".into(), QUAD_OBJ.as_bytes().to_vec()));
    out.push((
        "seed-obj-ngon-relative".into(),
        b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0.5 1.5 0\nv 0 1 0\nf -5 -4 -3 -2 -1\nf 1//0 2 3\n".to_vec(),
    ));
    out
}

/// The seeds do what their names say: valid batches train, the edge batches
/// hit every rejection kind, the overflow seed overflows; the shared and
/// hand-made valid scenes load, the broken ones are refused.
#[test]
fn seeds_are_meaningful() {
    for (name, input) in training_seeds() {
        let o = fuzz_checks::training_step(&input);
        assert!(o.created && o.accepted > 0, "{name}: {o:?}");
        if name.ends_with("-valid") || name.contains("params") {
            assert!(o.steps > 0 && o.skipped == 0, "{name}: {o:?}");
            assert_eq!(o.rejected, [0; 4], "{name}");
        }
        if name.ends_with("-edges") {
            assert!(o.rejected.iter().all(|&k| k > 0), "{name}: {o:?}");
        }
        if name.ends_with("-overflow") {
            assert!(o.overflowed > 0, "{name}: {o:?}");
        }
    }
    let read = |meshes: &[(&str, &str)], path: &std::path::Path| {
        let name = path.to_string_lossy();
        meshes
            .iter()
            .find(|m| m.0 == name)
            .map(|m| m.1.as_bytes().to_vec())
            .ok_or_else(|| std::io::Error::from(std::io::ErrorKind::NotFound))
    };
    let mut loaded = Vec::new();
    for (name, input) in scene_seeds() {
        let text = String::from_utf8(input).unwrap();
        let (xml, meshes) = fuzz_checks::split_scene_input(&text);
        let result = host_demo::scene::load::xml::load_str_with(
            xml,
            &name,
            std::path::Path::new(""),
            &|p| read(&meshes, p),
        );
        if let Ok(scene) = &result {
            fuzz_checks::check_scene(&name, scene);
            loaded.push(name);
        }
    }
    let mut expected = vec![
        "seed-conductor-obj",
        "seed-sampler-film",
        "seed-sphere-light",
        "seed-shared-cornell-box",
        "seed-shared-veach-mis",
    ];
    expected.sort_unstable();
    loaded.sort();
    assert_eq!(loaded, expected);
}

/// Writes the hand-made seeds into `fuzz/corpus/{training_step,scene_parser}`:
/// `cargo test --release -p guiding-tests --test fuzz_corpus -- --ignored write_seed_corpora`.
#[test]
#[ignore = "writes the seed corpora; run by hand"]
fn write_seed_corpora() {
    for (target, seeds) in [
        ("training_step", training_seeds()),
        ("scene_parser", scene_seeds()),
        ("c_api", c_api_seeds()),
    ] {
        let dir = corpus_dir(target);
        std::fs::create_dir_all(&dir).unwrap();
        for (name, bytes) in seeds {
            std::fs::write(dir.join(name), bytes).unwrap();
        }
    }
}
