//! Cases of this family (to be filled in).

use super::Case;

/// Every case of this family.
#[must_use]
pub fn cases() -> Vec<Case> {
    Vec::new()
}
