//! The data map: the declarative table and the process image behind it. No I/O.

mod image;
pub mod points;
pub mod table;

pub use image::{Image, WritePolicy, Written};
pub use table::{Access, COIL_COUNT, CoilView, Encoding, REGISTER_COUNT, Update};
