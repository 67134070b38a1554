//! [`named_enum!`](crate::named_enum): a field-less enum written once, as one table of its variants and
//! their names, with the list of every variant and each one's name made from that table.

/// Declares a field-less enum from a table `Variant [= code] => "name",` (attributes and doc comments on
/// the enum and on each variant as usual), with, in an `impl` of the enum:
/// - `ALL`: every variant, in declaration order;
/// - `name(self) -> &'static str`: the variant's name (as the command line, files, JSON and traces write it).
///
/// ```
/// voxhap_core::named_enum! {
///     #[derive(Debug, Clone, Copy, PartialEq)]
///     pub enum Side {
///         /// The outer side.
///         Outer => "outer",
///         Inner => "inner",
///     }
/// }
/// assert_eq!(Side::ALL, [Side::Outer, Side::Inner]);
/// assert_eq!(Side::Inner.name(), "inner");
/// ```
#[macro_export]
macro_rules! named_enum {
    (
        $(#[$meta:meta])*
        $vis:vis enum $enum:ident {
            $(
                $(#[$variant_meta:meta])*
                $variant:ident $(= $code:literal)? => $name:literal,
            )+
        }
    ) => {
        $(#[$meta])*
        $vis enum $enum {
            $(
                $(#[$variant_meta])*
                $variant $(= $code)?,
            )+
        }

        impl $enum {
            /// Every variant, in declaration order.
            pub const ALL: [$enum; [$($name),+].len()] = [$($enum::$variant),+];

            /// The variant's name, as the command line, files, JSON and traces write it.
            pub fn name(self) -> &'static str {
                match self {
                    $($enum::$variant => $name,)+
                }
            }
        }
    };
}
