//! svpack: silhouette shadow-volume geometry for WebGL 1.
//!
//! Data path: [`load`] → [`weld`] → [`topology`] → [`layout`] → [`format`](mod@format).
pub mod accuracy;
pub mod alloc;
pub mod build;
pub mod compression;
pub mod error;
pub mod evaluate;
pub mod evaluate_indexed;
pub mod evaluate_ordered;
pub mod evaluate_simd;
pub mod exact;
pub mod file_bytes;
pub mod format;
pub mod hardcases;
mod hint;
pub mod layout;
pub mod lint;
pub mod load;
pub mod multiplicity;
pub mod parallel;
mod pool;
mod position_index;
pub mod quantize;
pub mod removals;
pub mod report;
pub mod shadow;
mod slots;
pub mod topology;
pub mod trace;
pub mod verify;
pub mod weld;
