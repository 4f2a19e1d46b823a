//! What the tests share, and the product does not: the bytes captured from
//! real traffic ([`fixtures`]), an in-memory duplex stream for sessions
//! ([`duplex`]), and a reference framer written from the specification
//! alone ([`framer`], with what a reply may be in [`reply`]), against which
//! the unit tests, the fuzz targets and the system tests check the server.
//!
//! It depends on neither `modbus` nor `adapter` (they dev-depend on it): it
//! is an independent reference, not a second copy of their code.

pub mod duplex;
pub mod fixtures;
pub mod framer;
pub mod reply;
