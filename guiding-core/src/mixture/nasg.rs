//! Mixtures of NASG lobes (placeholder: being written).
