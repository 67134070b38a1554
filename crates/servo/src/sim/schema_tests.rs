//! Tests of `schema`.

use super::*;
use crate::sim::scenario::{LoadedScenario, Purpose, Scenario};
use std::collections::BTreeSet;
use voxhap_record::error_chain as chain;

/// Volumes every test document has (modes refer to them by name).
const VOLUMES: &str = "[[volumes]]\nname = \"density\"\nbuiltin = \"sphere\"\n\n\
                           [[volumes]]\nname = \"flow\"\nbuiltin = \"burgers\"\n";
/// Top-level keys of every document but the top level's own.
const TOP: &str = "k_n_per_m = 500.0\nduration_s = 1.0\nstart_m = [0.0, 0.0, 0.04]";

/// The section's base lines with `changes` applied: `Some(value)` sets a key, `None` removes it.
fn body(section: &SchemaSection, changes: &[(&str, Option<&str>)]) -> String {
    let name_of = |line: &str| line.split('=').next().unwrap_or("").trim().to_owned();
    let mut lines: Vec<String> = section
        .base
        .lines()
        .filter(|line| !changes.iter().any(|(k, _)| *k == name_of(line)))
        .map(str::to_owned)
        .collect();
    for (k, v) in changes {
        if let Some(v) = v {
            lines.push(format!("{k} = {v}"));
        }
    }
    lines.join("\n")
}

fn document(section: &SchemaSection, changes: &[(&str, Option<&str>)]) -> String {
    if section.header.is_empty() {
        format!("{}\n\n{VOLUMES}", body(section, changes))
    } else {
        format!(
            "{TOP}\n\n{VOLUMES}\n{}\n{}\n",
            section.header,
            body(section, changes)
        )
    }
}

/// Parses, validates and loads `text` as `sim` (or `serve`) does.
fn load(text: &str, purpose: Purpose) -> Result<LoadedScenario, String> {
    let scenario = Scenario::parse_for(text, "t.toml", purpose).map_err(|e| chain(&e))?;
    scenario
        .load(std::path::Path::new("."), "t.toml")
        .map_err(|e| chain(&e))
}

/// Every key of every section, with its section.
fn every_key() -> impl Iterator<Item = (&'static SchemaSection, &'static SchemaKey)> {
    SCENE_SCHEMA
        .iter()
        .flat_map(|section| section.keys.iter().map(move |key| (section, key)))
}

/// Every key is checked as `sim` reads it (`serve` reads the same keys; it only does not need `duration_s`).
fn purpose_for(_section: &SchemaSection, _key: &SchemaKey) -> Purpose {
    Purpose::Sim
}

#[test]
fn every_base_document_loads() {
    for section in SCENE_SCHEMA {
        let text = document(section, &[]);
        load(&text, Purpose::Sim).unwrap_or_else(|e| panic!("{}: {e}\n{text}", section.title));
    }
}

#[test]
fn the_keys_are_the_fields_the_parser_accepts() {
    let groups: BTreeSet<&str> = SCENE_SCHEMA.iter().map(|s| s.group).collect();
    for group in groups {
        let sections: Vec<&SchemaSection> =
            SCENE_SCHEMA.iter().filter(|s| s.group == group).collect();
        let documented: BTreeSet<&str> = sections
            .iter()
            .flat_map(|s| s.keys.iter().map(|k| k.name))
            .collect();
        let text = document(sections[0], &[("zzz_unknown", Some("1"))]);
        let error = load(&text, Purpose::Sim).expect_err("an unknown key is refused");
        let expected = error
            .split("expected")
            .nth(1)
            .unwrap_or_else(|| panic!("{group}: no field list in {error:?}"));
        let accepted: BTreeSet<&str> = expected.split('`').skip(1).step_by(2).collect();
        assert_eq!(
            documented, accepted,
            "{group}: the table's keys against the parser's ({error})"
        );
    }
}

/// The tables read by `kind` or `shape` (device::sim::tagged): each section lists exactly the keys of
/// its kind (the first section of a table also lists the tag).
const TAGGED_GROUPS: &[&str] = &["workspace", "path", "profile"];

#[test]
fn a_key_of_another_kind_is_refused_by_name() {
    let mut checked = 0;
    for section in SCENE_SCHEMA
        .iter()
        .filter(|s| TAGGED_GROUPS.contains(&s.group))
    {
        let takes: BTreeSet<&str> = section.keys.iter().map(|k| k.name).collect();
        let others = SCENE_SCHEMA
            .iter()
            .filter(|s| s.group == section.group)
            .flat_map(|s| s.keys.iter())
            .filter(|k| !takes.contains(k.name) && !["kind", "shape"].contains(&k.name))
            .filter(|k| !k.example.is_empty());
        for other in others {
            let text = document(section, &[(other.name, Some(other.example))]);
            let error = load(&text, Purpose::Sim).expect_err("a key of another kind");
            let table = table_of(&text);
            assert!(
                error.contains(&format!("{table}: "))
                    && error.contains(&format!("takes no key `{}`", other.name)),
                "{}: {} = {}: {error}",
                section.title,
                other.name,
                other.example
            );
            checked += 1;
        }
    }
    assert!(checked >= 40, "{checked} keys checked");
}

#[test]
fn a_default_written_out_is_the_same_as_leaving_the_key_out() {
    let mut checked = 0;
    for (section, key) in every_key() {
        let KeyDefault::Value(value) = key.default else {
            continue;
        };
        let purpose = purpose_for(section, key);
        let written = load(&document(section, &[(key.name, Some(value))]), purpose)
            .unwrap_or_else(|e| panic!("{}.{} = {value}: {e}", section.title, key.name));
        let left_out = load(&document(section, &[(key.name, None)]), purpose)
            .unwrap_or_else(|e| panic!("{} without {}: {e}", section.title, key.name));
        let same = written.scenario == left_out.scenario || {
            // `Option` fields (a mode's `side`, `enabled`): compare the built modes.
            let mut a = written.scenario.clone();
            let mut b = left_out.scenario.clone();
            a.modes.clear();
            b.modes.clear();
            a == b && written.scene.modes() == left_out.scene.modes()
        };
        assert!(
            same,
            "{}: {} = {value} is not the default",
            section.title, key.name
        );
        checked += 1;
    }
    assert!(checked >= 9, "{checked} defaults checked");
}

/// Values a key must accept and refuse, from its `Accepts`.
fn edges(accepts: Accepts, example: &str) -> (Vec<String>, Vec<String>) {
    let number = |x: f64| format!("{x:?}");
    let bad_numbers = || vec!["nan".to_owned(), "inf".to_owned()];
    match accepts {
        Positive => (
            vec![example.to_owned()],
            [bad_numbers(), vec![number(0.0), number(-1.0)]].concat(),
        ),
        PositiveAtMost(hi) => (
            vec![number(hi), example.to_owned()],
            [
                bad_numbers(),
                vec![number(0.0), number(-1.0), number(hi * 1.5)],
            ]
            .concat(),
        ),
        NonNegative => (
            vec![number(0.0), example.to_owned()],
            [bad_numbers(), vec![number(-1e-6)]].concat(),
        ),
        NonNegativeAtMost(hi) => (
            vec![number(0.0), number(hi), example.to_owned()],
            [bad_numbers(), vec![number(-1e-6), number(hi * 1.5)]].concat(),
        ),
        // A range from 0 (a coefficient, a strength) is left just below 0.
        Between(lo, hi) if lo == 0.0 => (
            vec![number(lo), number(hi)],
            [bad_numbers(), vec![number(-1e-6), number(hi * 2.0)]].concat(),
        ),
        Between(lo, hi) => (
            vec![number(lo), number(hi)],
            [
                bad_numbers(),
                vec![number(lo * 0.5), number(hi * 2.0), number(-lo)],
            ]
            .concat(),
        ),
        Count(lo, hi) => {
            let mut refused = vec![(hi + 1).to_string(), "-1".to_owned(), "1.5".to_owned()];
            if lo > 0 {
                refused.push((lo - 1).to_string());
            }
            (vec![lo.to_string(), hi.to_string()], refused)
        }
        Vector => (
            vec![example.to_owned()],
            vec!["[nan, 0.0, 0.0]".to_owned(), "[0.0, 0.0]".to_owned()],
        ),
        Direction => (
            vec![example.to_owned()],
            vec!["[0.0, 0.0, 0.0]".to_owned(), "[inf, 0.0, 0.0]".to_owned()],
        ),
        Points => (
            vec![example.to_owned()],
            vec!["[]".to_owned(), "[[0.0, nan, 0.0]]".to_owned()],
        ),
        VectorWithin(limit) => (
            vec![example.to_owned(), at_limit(example, limit)],
            vec![
                "[nan, 0.0, 0.0]".to_owned(),
                "[0.0, 0.0]".to_owned(),
                format!("[{:?}, 0.0, 0.0]", limit * 2.0),
                format!("[0.0, 0.0, {:?}]", -limit * 1.001),
            ],
        ),
        PointsWithin(limit, most) => {
            let point = example.trim_start_matches('[').trim_end_matches(']');
            let many = vec![format!("[{point}]"); most as usize + 1].join(", ");
            let full = vec![format!("[{point}]"); most as usize].join(", ");
            (
                vec![
                    example.to_owned(),
                    format!("[{}]", at_limit(&format!("[{point}]"), limit)),
                    format!("[{full}]"),
                ],
                vec![
                    "[]".to_owned(),
                    "[[0.0, nan, 0.0]]".to_owned(),
                    format!("[[{:?}, 0.0, 0.0]]", limit * 2.0),
                    format!("[{many}]"),
                ],
            )
        }
        Transfer => (
            vec![example.to_owned()],
            vec![
                "[[0.5, 1.0], [0.2, 2.0]]".to_owned(),
                "[[0.0, -1.0]]".to_owned(),
                "[[0.0, 1000000.1]]".to_owned(),
                "[[-1e301, 0.0], [0.0, 1.0]]".to_owned(),
            ],
        ),
        // The list itself is compared with the parser's in `the_choices_are_the_parsers`.
        OneOf(_) => (
            vec![example.to_owned()],
            vec!["\"no-such-value\"".to_owned()],
        ),
        Bool => (
            vec!["true".to_owned(), "false".to_owned()],
            vec!["1".to_owned()],
        ),
        Text | Table(_) => (Vec::new(), Vec::new()),
    }
}

/// The example vector `[x, y, z]` with each non-zero coordinate moved out to `limit`, keeping its sign (so a
/// box's corners stay ordered).
fn at_limit(example: &str, limit: f64) -> String {
    let coordinates: Vec<String> = example
        .trim_matches(['[', ']'])
        .split(',')
        .map(|c| {
            let c: f64 = c.trim().parse().expect("an example coordinate");
            format!("{:?}", limit * c.signum() * f64::from(u8::from(c != 0.0)))
        })
        .collect();
    format!("[{}]", coordinates.join(", "))
}

/// The table a document's last lines are in, as an error names it (`path.profile`, `modes[1]`).
fn table_of(text: &str) -> String {
    let header = text
        .lines()
        .rfind(|line| line.starts_with('['))
        .unwrap_or_default();
    match header.strip_prefix("[[").and_then(|h| h.strip_suffix("]]")) {
        Some(name) => {
            let index = text.lines().filter(|line| *line == header).count() - 1;
            format!("{name}[{index}]")
        }
        None => header.trim_matches(['[', ']']).to_owned(),
    }
}

/// The full path of `key` of `section` in its document `text` (`path.profile.force_n`, `modes[1].mu`).
fn key_path(section: &SchemaSection, text: &str, key: &str) -> String {
    if section.header.is_empty() {
        return key.to_owned();
    }
    format!("{}.{key}", table_of(text))
}

/// Whether `error` names `path` as a whole key (not as the end of a longer one, `path.duration_s` for
/// `duration_s`).
fn names_key(error: &str, path: &str) -> bool {
    error.match_indices(path).any(|(at, _)| {
        let before = error[..at].chars().next_back();
        let after = error[at + path.len()..].chars().next();
        !before.is_some_and(|c| c.is_alphanumeric() || "_.]".contains(c))
            && !after.is_some_and(|c| c.is_alphanumeric() || c == '_')
    })
}

#[test]
fn every_range_holds_at_its_edges() {
    let mut checked = 0;
    let mut wrong = Vec::new();
    for (section, key) in every_key() {
        // A `kind` or `shape` changes which other keys the table needs: its values are checked
        // by the sections of each kind loading.
        if ["kind", "shape"].contains(&key.name) {
            continue;
        }
        let purpose = purpose_for(section, key);
        let (accepted, refused) = edges(key.accepts, key.example);
        for value in &accepted {
            let text = document(section, &[(key.name, Some(value))]);
            if let Err(e) = load(&text, purpose) {
                wrong.push(format!(
                    "{}: {} = {value} should be accepted: {e}",
                    section.title, key.name
                ));
            }
            checked += 1;
        }
        for value in &refused {
            let text = document(section, &[(key.name, Some(value))]);
            match load(&text, purpose) {
                Ok(_) => wrong.push(format!(
                    "{}: {} = {value} should be refused",
                    section.title, key.name
                )),
                Err(e) if names_key(&e, &key_path(section, &text, key.name)) => {}
                Err(e) => wrong.push(format!(
                    "{}: {} = {value}: the error does not name the key {}: {e}",
                    section.title,
                    key.name,
                    key_path(section, &text, key.name)
                )),
            }
            checked += 1;
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
    assert!(checked >= 150, "{checked} values checked");
}

#[test]
fn the_choices_are_the_parsers() {
    let mut checked = 0;
    for (section, key) in every_key() {
        let OneOf(names) = key.accepts else {
            continue;
        };
        let text = document(section, &[(key.name, Some("\"no-such-value\""))]);
        let error = load(&text, purpose_for(section, key)).expect_err("refused");
        let Some(list) = error.split("expected").nth(1) else {
            continue; // checked by code, not by serde (a built-in volume's name)
        };
        let parsed: BTreeSet<&str> = list.split('`').skip(1).step_by(2).collect();
        let documented: BTreeSet<&str> = names.iter().copied().collect();
        assert_eq!(
            documented, parsed,
            "{}: {} ({error})",
            section.title, key.name
        );
        checked += 1;
    }
    assert!(checked >= 5, "{checked} lists checked");
}

#[test]
fn examples_load_and_every_key_is_described() {
    for (section, key) in every_key() {
        assert!(!key.meaning.is_empty(), "{}.{}", section.title, key.name);
        if !matches!(key.accepts, Table(_)) && !key.example.is_empty() {
            let text = document(section, &[(key.name, Some(key.example))]);
            load(&text, purpose_for(section, key)).unwrap_or_else(|e| {
                panic!(
                    "{}: example {} = {}: {e}",
                    section.title, key.name, key.example
                )
            });
        }
    }
}
