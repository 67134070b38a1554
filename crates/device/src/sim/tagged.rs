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
//! enum).

/// `[("key", table.key.is_some()), ...]` for the `Option` fields named: the keys given in a table, for
/// [`KindKeys::new`] (each name is the field's own, so the two cannot drift apart).
macro_rules! given_keys {
    ($table:ident: $($key:ident),+ $(,)?) => {
        [$((stringify!($key), $table.$key.is_some())),+]
    };
}
pub(super) use given_keys;

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
    pub(super) fn only(&self, takes: &[&str]) -> Result<(), String> {
        let Some((key, _)) = self
            .given
            .iter()
            .find(|(key, given)| *given && !takes.contains(key))
        else {
            return Ok(());
        };
        let keys = if takes.is_empty() {
            "it takes none".to_owned()
        } else {
            let quoted: Vec<String> = takes.iter().map(|k| format!("`{k}`")).collect();
            format!("its keys: {}", quoted.join(", "))
        };
        Err(format!(
            "{} = \"{}\" takes no key `{key}` ({keys})",
            self.tag, self.kind
        ))
    }

    /// The value of `key`, which this kind needs.
    pub(super) fn need<T>(&self, key: &str, value: Option<T>) -> Result<T, String> {
        value.ok_or_else(|| {
            format!(
                "missing field `{key}` ({} = \"{}\" needs it)",
                self.tag, self.kind
            )
        })
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
            keys.only(&["from_m", "to_m"]),
            Err("kind = \"line\" takes no key `radius_m` (its keys: `from_m`, `to_m`)".to_owned())
        );
        assert_eq!(keys.only(&["from_m", "radius_m"]), Ok(()));
        assert_eq!(
            KindKeys::new("shape", "unbounded", &given).only(&[]),
            Err("shape = \"unbounded\" takes no key `from_m` (it takes none)".to_owned())
        );
        assert_eq!(
            keys.need("to_m", None::<f64>),
            Err("missing field `to_m` (kind = \"line\" needs it)".to_owned())
        );
        assert_eq!(keys.need("from_m", Some(1.0)), Ok(1.0));
    }
}
