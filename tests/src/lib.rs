//! Shared helpers of the system tests: network namespaces and the programs
//! under test.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing)]

pub mod netns;
