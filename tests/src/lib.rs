//! Shared helpers of the system tests: network namespaces and the programs
//! under test.

pub mod hal_sim;
pub mod netns;
pub mod qemu;
