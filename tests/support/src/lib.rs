//! What the tests share, and the product does not: the bytes captured from
//! real traffic ([`fixtures`]), an in-memory duplex stream for sessions
//! ([`duplex`]), and a reference framer written from the specification
//! alone ([`framer`]), against which the unit tests, the fuzz targets and the
//! system tests check the server's framing.

pub mod fixtures;
