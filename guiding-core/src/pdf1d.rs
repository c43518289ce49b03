//! Piecewise 1D densities (placeholder: being written).
