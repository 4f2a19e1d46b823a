//! Board support: one module per board, each behind its cargo feature.
//! Nothing outside this folder and `src/bin/` names a chip, a pin or a HAL crate.

#[cfg(feature = "mps2-an386")]
pub mod mps2_an386;
#[cfg(feature = "nucleo-f429zi")]
pub mod nucleo_f429zi;
