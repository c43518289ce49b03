//! The benchmark workloads of the guiding library, defined once.
//!
//! Two harnesses time them: the criterion benches of this crate
//! (`cargo bench -p guiding-bench --bench <name>`, statistics and outlier
//! analysis for kernel work) and the micro-benchmark section of
//! `host-demo bench` (a median of a few runs, next to the equal-time
//! renders, so one report holds both). Both build their inputs with
//! [`inputs`], time with [`timing`] and run the same workload types
//! ([`distribution::DistributionCase`], [`mlp::MlpWorkload`],
//! [`gradient::VmfGradientWorkload`]), so a number in the report and a
//! criterion line of the same name measure the same code on the same data.
//!
//! Every input comes from the kernels' generator ([`guiding_core::rng::Rng`])
//! with a fixed seed.

pub mod distribution;
pub mod gradient;
pub mod inputs;
pub mod mlp;
pub mod timing;
