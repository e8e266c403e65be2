//! svpack: silhouette shadow-volume geometry for WebGL 1.
//!
//! Data path: [`load`] → [`weld`] → [`topology`] → [`layout`] → [`format`].
pub mod error;
pub mod load;
pub mod format;
pub mod layout;
pub mod multiplicity;
pub mod topology;
pub mod weld;
pub mod build;
pub mod report;
