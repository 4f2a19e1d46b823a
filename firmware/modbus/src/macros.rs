//! The macro that writes a code table (as smoltcp's `enum_with_unknown!`).

/// Defines a table of one-byte codes from one list: each code is written
/// once, and every conversion, name and doc line is generated from it.
///
/// ```text
/// code_table! {
///     /// What the table is.
///     pub enum Table {
///         display: "label",
///         /// Optional notes on one code.
///         Variant = 0x01, "spec name", section "6.1";
///         ...
///     }
/// }
/// ```
///
/// The enum gets an `Unknown(u8)` fallback, so every byte has a value and
/// round-trips; `From<u8>`; `From<Table> for u8` and `const fn code`;
/// `const fn name` (the spec's name, "unknown" for the fallback); `Display`
/// as `label 0b: spec name`; `Clone, Copy, Debug, PartialEq, Eq` and
/// `defmt::Format` under the `defmt` feature. Each variant's doc starts with
/// its code, name and section of the Modbus Application Protocol V1.1b3.
///
/// Each code is also its variant's discriminant (`repr(u8)`), so `code()` is
/// a compare and a select rather than a lookup, and a match on the table is a
/// match on the byte: this keeps the firmware as small as with fieldless
/// enums. `Unknown` takes the discriminant after the last code, so list the
/// codes in ascending order (the compiler rejects a collision).
macro_rules! code_table {
    (
        $(#[$meta:meta])*
        $vis:vis enum $Table:ident {
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
        #[repr(u8)]
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
            Unknown(u8),
        }

        impl $Table {
            /// The code on the wire.
            #[inline]
            pub const fn code(self) -> u8 {
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

        impl From<u8> for $Table {
            #[inline]
            fn from(code: u8) -> Self {
                match code {
                    $( $code => Self::$Variant, )+
                    other => Self::Unknown(other),
                }
            }
        }

        impl From<$Table> for u8 {
            #[inline]
            fn from(value: $Table) -> u8 {
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
