//! svpack: silhouette shadow-volume geometry for WebGL 1.
//!
//! Data path: [`load`] → [`weld`] → [`topology`] → [`layout`] → [`format`].
pub mod error;
pub mod load;
