//! Tables whose keys depend on a tag key (`[path]` on `kind`, `[path.profile]` and `[arm.workspace]` on
//! `shape`), read so that every error names its key.
//!
//! Where it sits: between a scene file's TOML and the enums of this module ([`super::HandPath`],
//! [`super::ForceProfile`], [`super::Workspace`]); read once, off the servo path. serde reads an internally
//! tagged enum through a buffer, which loses the path of the keys inside: a wrong-typed value was reported at
//! the table (`path: invalid type: string "fast", expected f64`), not at its key. So each of these enums is
//! read as a plain struct holding every key of every kind (`deny_unknown_fields`), whose errors serde (and
//! `serde_path_to_error`) report at the key (`path.speed_m_per_s: invalid type ...`), and is then converted
//! with `TryFrom`, which [`KindKeys`] helps check: no key of another kind is given, and every key the kind
//! needs is. Those messages name the key too: ``path: kind = "line" takes no key `radius_m` (...)``,
//! ``path: missing field `duration_s` (kind = "line" needs it)``. Serialising is unchanged (the tagged
//! enum). `tagged_table!` declares the tag enum, the struct and the `TryFrom` of each such table, and the check
//! of every key with what it accepts.

/// Declares the tag enum of a tagged table (its scene-file names and each kind's keys), the table struct
/// holding every key of every kind as an `Option`, the `TryFrom` from that struct to the target enum,
/// which refuses a key of another kind ([`KindKeys::only`]) and a missing key ([`KindKeys::need`]), and the
/// target's `check_keys`, which checks each key with what it accepts ([`super::keys`]), in the order written,
/// naming it `prefix.key`. Each kind's keys are the target variant's fields, named once here with what they
/// accept, so the table, the checks and the variant cannot drift apart.
///
/// ```text
/// tagged_table! {
///     Target by tag_key at "prefix",
///     /// docs of the tag enum
///     kinds TagEnum { Variant = "name" { key: accepts, ... }, ... }
///     /// docs of the table struct
///     table TableStruct { key: Type, ... }
/// }
/// ```
macro_rules! tagged_table {
    (
        $target:ident by $tag:ident at $prefix:literal,
        $(#[$kind_doc:meta])*
        kinds $kind:ident {
            $($variant:ident = $name:literal { $($needs:ident: $accepts:expr),* }),+ $(,)?
        }
        $(#[$table_doc:meta])*
        table $table:ident { $($key:ident: $ty:ty),+ $(,)? }
    ) => {
        $(#[$kind_doc])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize)]
        pub enum $kind {
            $(#[serde(rename = $name)] $variant,)+
        }

        impl $kind {
            /// The name written in a scene file.
            pub fn name(self) -> &'static str {
                match self {
                    $($kind::$variant => $name,)+
                }
            }

            /// The keys a table of this kind takes (besides its tag); all of them are needed.
            pub fn keys(self) -> &'static [&'static str] {
                match self {
                    $($kind::$variant => &[$(stringify!($needs)),*],)+
                }
            }
        }

        $(#[$table_doc])*
        #[derive(serde::Deserialize)]
        #[serde(deny_unknown_fields)]
        struct $table {
            $tag: $kind,
            $($key: Option<$ty>,)+
        }

        impl TryFrom<$table> for $target {
            type Error = $crate::sim::TaggedTableError;

            fn try_from(table: $table) -> Result<Self, Self::Error> {
                let given = [$((stringify!($key), table.$key.is_some())),+];
                let keys =
                    $crate::sim::tagged::KindKeys::new(stringify!($tag), table.$tag.name(), &given);
                keys.only(table.$tag.keys())?;
                Ok(match table.$tag {
                    $($kind::$variant => $target::$variant {
                        $($needs: keys.need(stringify!($needs), table.$needs)?,)*
                    },)+
                })
            }
        }

        impl $target {
            /// Checks every key with what it accepts, in the order declared (`tagged_table!`).
            fn check_keys(&self) -> Result<(), $crate::sim::SimError> {
                match self {
                    $($target::$variant { $($needs),* } => {
                        $($crate::sim::keys::KeyCheck::check(
                            &$accepts,
                            concat!($prefix, ".", stringify!($needs)),
                            $needs,
                        )?;)*
                    })+
                }
                Ok(())
            }
        }
    };
}
pub(super) use tagged_table;

/// The keys given in one tagged table, for the checks of its `TryFrom`.
pub(super) struct KindKeys<'a> {
    /// The tag key: `kind` or `shape`.
    tag: &'static str,
    /// The tag's value, e.g. `line`.
    kind: &'static str,
    /// Every key the table may hold (the tag excluded), with whether it was given.
    given: &'a [(&'static str, bool)],
}

impl<'a> KindKeys<'a> {
    /// The table of `tag = "kind"` with these keys given.
    pub(super) fn new(
        tag: &'static str,
        kind: &'static str,
        given: &'a [(&'static str, bool)],
    ) -> Self {
        KindKeys { tag, kind, given }
    }

    /// Refuses a key given that is not one of `takes` (the keys of this kind), naming it and the kind's keys.
    pub(super) fn only(&self, takes: &'static [&'static str]) -> Result<(), TaggedTableError> {
        match self
            .given
            .iter()
            .find(|(key, given)| *given && !takes.contains(key))
        {
            Some(&(key, _)) => Err(TaggedTableError::KeyOfAnotherKind {
                tag: self.tag,
                kind: self.kind,
                key,
                takes,
            }),
            None => Ok(()),
        }
    }

    /// The value of `key`, which this kind needs.
    pub(super) fn need<T>(
        &self,
        key: &'static str,
        value: Option<T>,
    ) -> Result<T, TaggedTableError> {
        value.ok_or(TaggedTableError::MissingKey {
            tag: self.tag,
            kind: self.kind,
            key,
        })
    }
}

/// Why a tagged table (`[path]`, `[path.profile]`, `[arm.workspace]`) does not fit its kind. serde puts the
/// table's path in front (`path: ...`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum TaggedTableError {
    /// A key was given that this kind does not take.
    #[error("{tag} = \"{kind}\" takes no key `{key}` ({})", describe_keys(.takes))]
    KeyOfAnotherKind {
        /// The tag key: `kind` or `shape`.
        tag: &'static str,
        /// The tag's value.
        kind: &'static str,
        /// The key given.
        key: &'static str,
        /// The keys this kind takes.
        takes: &'static [&'static str],
    },
    /// A key this kind needs is missing.
    #[error("missing field `{key}` ({tag} = \"{kind}\" needs it)")]
    MissingKey {
        /// The tag key: `kind` or `shape`.
        tag: &'static str,
        /// The tag's value.
        kind: &'static str,
        /// The key missing.
        key: &'static str,
    },
}

/// "its keys: `a`, `b`", or "it takes none".
fn describe_keys(takes: &[&str]) -> String {
    if takes.is_empty() {
        "it takes none".to_owned()
    } else {
        let quoted: Vec<String> = takes.iter().map(|k| format!("`{k}`")).collect();
        format!("its keys: {}", quoted.join(", "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_key_of_another_kind_and_a_missing_key_are_named() {
        let given = [("at_m", false), ("from_m", true), ("radius_m", true)];
        let keys = KindKeys::new("kind", "line", &given);
        assert_eq!(
            keys.only(&["from_m", "to_m"]).map_err(|e| e.to_string()),
            Err("kind = \"line\" takes no key `radius_m` (its keys: `from_m`, `to_m`)".to_owned())
        );
        assert_eq!(keys.only(&["from_m", "radius_m"]), Ok(()));
        assert_eq!(
            KindKeys::new("shape", "unbounded", &given)
                .only(&[])
                .map_err(|e| e.to_string()),
            Err("shape = \"unbounded\" takes no key `from_m` (it takes none)".to_owned())
        );
        assert_eq!(
            keys.need("to_m", None::<f64>).map_err(|e| e.to_string()),
            Err("missing field `to_m` (kind = \"line\" needs it)".to_owned())
        );
        assert_eq!(keys.need("from_m", Some(1.0)), Ok(1.0));
    }
}
