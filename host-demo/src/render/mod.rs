//! Rendering: the options, the pass [`schedule`], the [`wavefront`] driver and its
//! direction-sampling [`strategy`], images and their [`output`] and [`compare`]ison.

pub mod compare;
pub mod output;
pub mod schedule;
pub mod strategy;
pub mod wavefront;
