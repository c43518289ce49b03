//! Normalised anisotropic spherical Gaussian lobe (placeholder: being written).
