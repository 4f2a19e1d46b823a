//! The data map: the declarative table and the process image behind it. No I/O.

mod image;
pub mod names;
pub mod points;
pub mod table;

pub use image::{Image, WritePolicy, Written};
pub use table::{COIL_COUNT, CoilView, Encoding, Permission, REGISTER_COUNT, Update};
