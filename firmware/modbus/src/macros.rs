//! The macro that writes a code table (as smoltcp's `enum_with_unknown!`).

/// Defines a table of codes from one list: each code is written once, and
/// every conversion, name and doc line is generated from it. Codes are one
/// byte (`u8`), or two for a table of sub-functions (`u16`).
///
/// ```text
/// code_table! {
///     /// What the table is.
///     pub enum Table: u8 {
///         display: "label",
///         /// Optional notes on one code.
///         Variant = 0x01, "spec name", section "6.1";
///         ...
///     }
/// }
/// ```
///
/// The enum gets an `Unknown(code)` fallback, so every code has a value and
/// round-trips; `From` the code's type and back, and `const fn code`;
/// `const fn name` (the spec's name, "unknown" for the fallback); `Display`
/// as `label 0b: spec name`; `Clone, Copy, Debug, PartialEq, Eq` and
/// `defmt::Format` under the `defmt` feature. Each variant's doc starts with
/// its code, name and section of the Modbus Application Protocol V1.1b3.
///
/// Each code is also its variant's discriminant (`repr(u8)`, `repr(u16)`),
/// so `code()` is a compare and a select rather than a lookup, and a match on
/// the table is a match on the code: this keeps the firmware as small as
/// with fieldless enums. `Unknown` takes the discriminant after the last code, so list the
/// codes in ascending order (the compiler rejects a collision).
macro_rules! code_table {
    (
        $(#[$meta:meta])*
        $vis:vis enum $Table:ident: $repr:ident {
            display: $label:literal,
            $(
                $(#[$doc:meta])*
                $Variant:ident = $code:literal, $name:literal, section $section:literal;
            )+
        }
    ) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        #[repr($repr)]
        $vis enum $Table {
            $(
                #[doc = concat!(
                    "`", stringify!($code), "` ", $name,
                    " (Modbus Application Protocol V1.1b3, ", $section, ")."
                )]
                #[doc = ""]
                $(#[$doc])*
                $Variant = $code,
            )+
            /// A code this table does not list, kept as it came so that it
            /// round-trips.
            Unknown($repr),
        }

        impl $Table {
            /// The code on the wire.
            #[inline]
            pub const fn code(self) -> $repr {
                match self {
                    $( Self::$Variant => $code, )+
                    Self::Unknown(code) => code,
                }
            }

            /// The specification's name for the code; "unknown" for [`Self::Unknown`].
            pub const fn name(self) -> &'static str {
                match self {
                    $( Self::$Variant => $name, )+
                    Self::Unknown(_) => "unknown",
                }
            }
        }

        impl From<$repr> for $Table {
            #[inline]
            fn from(code: $repr) -> Self {
                match code {
                    $( $code => Self::$Variant, )+
                    other => Self::Unknown(other),
                }
            }
        }

        impl From<$Table> for $repr {
            #[inline]
            fn from(value: $Table) -> $repr {
                value.code()
            }
        }

        impl core::fmt::Display for $Table {
            fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                write!(f, concat!($label, " {:02x}: {}"), self.code(), self.name())
            }
        }
    };
}
