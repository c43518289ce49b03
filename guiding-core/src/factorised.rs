//! Factorised 2D directional densities (placeholder: being written).
