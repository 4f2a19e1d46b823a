//! Board support: one module per board, each behind its cargo feature.
//! Nothing outside this folder and `src/bin/` names a chip, a pin or a HAL crate.

// Host tests build the mps2 module for its LAN9118 driver logic (no MMIO there).
#[cfg(any(test, feature = "mps2-an386"))]
pub mod mps2_an386;
#[cfg(feature = "nucleo-f429zi")]
pub mod nucleo_f429zi;
// Host tests build the NUCLEO's settings and scaling on their own (no HAL there).
#[cfg(all(test, not(feature = "nucleo-f429zi")))]
#[path = "nucleo_f429zi/settings.rs"]
mod nucleo_f429zi_settings;
