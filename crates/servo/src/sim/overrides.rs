//! Scenario overrides: `--set key=value` for any key of a scenario file, applied to the parsed TOML before
//! the scenario is validated, so an override is checked exactly like the file itself.
//!
//! Where it sits: `voxhap sim --set`, `--duration`, `--rate` and `voxhap sweep` read the scenario text,
//! call [`apply_overrides`] and hand the result to `Scenario::parse_edited`. Keys are dotted paths with array
//! indices: `k_n_per_m`, `path.speed_m_per_s`, `modes[1].mu`, `modes[0].transfer[1][1]`, `path.points_m[2]`.
//! Values are TOML (`200`, `1e-3`, `[0.0, 0.0, 0.02]`, `"sphere"`); a value that is not TOML is taken as a
//! string, so `solver.kind=euler` works without quotes. A missing table on the way is created (`solver.kind`
//! without a `[solver]` table); an array index must exist. Errors name the override and the key.

use toml::{Table, Value};

/// Why an override could not be applied.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum OverrideError {
    /// The text is not `key=value`.
    #[error("--set {0:?}: expected KEY=VALUE, e.g. k_n_per_m=200 or modes[0].mu=0.4")]
    Syntax(String),
    /// The key path is malformed or does not fit the scenario.
    #[error("--set {text:?}: {problem}")]
    Key {
        /// The override as given.
        text: String,
        /// What is wrong.
        problem: KeyError,
    },
    /// The scenario text is not TOML.
    #[error("the scenario is not valid TOML: {0}")]
    Scenario(String),
}

/// Why a key path cannot be set in a scenario table.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum KeyError {
    /// A part of the path is not a key name.
    #[error("{part:?} is not a key name (letters, digits, '_', '-')")]
    BadName {
        /// The part as given.
        part: String,
    },
    /// An index is opened and never closed.
    #[error("{part:?}: '[' without ']'")]
    Unclosed {
        /// The part as given.
        part: String,
    },
    /// What is between the brackets is not a number.
    #[error("{part:?}: {index:?} is not an array index")]
    BadIndex {
        /// The part as given.
        part: String,
        /// The text between the brackets.
        index: String,
    },
    /// Text follows a closing bracket.
    #[error("{part:?}: unexpected {rest:?} after ']'")]
    Trailing {
        /// The part as given.
        part: String,
        /// The text after the bracket.
        rest: String,
    },
    /// The path walks into a value that is not a table.
    #[error("{walked} is not a table, so it has no key {name:?}")]
    NotATable {
        /// The path up to the value.
        walked: String,
        /// The key asked of it.
        name: String,
    },
    /// The path indexes a value that is not an array.
    #[error("{walked} is not an array, so it has no [{index}]")]
    NotAnArray {
        /// The path up to the value.
        walked: String,
        /// The index asked of it.
        index: usize,
    },
    /// The index is past the end of the array.
    #[error("{walked}[{index}]: {walked} has {len} elements (indices from 0)")]
    OutOfRange {
        /// The path up to the array.
        walked: String,
        /// The index asked.
        index: usize,
        /// The array's length.
        len: usize,
    },
    /// The key has no steps.
    #[error("{key:?}: empty key")]
    Empty {
        /// The key as given.
        key: String,
    },
}

/// One step of a key path.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Step {
    Key(String),
    Index(usize),
}

fn parse_path(key: &str) -> Result<Vec<Step>, KeyError> {
    let mut steps = Vec::new();
    for part in key.split('.') {
        let (name, mut rest) = match part.find('[') {
            Some(at) => (&part[..at], &part[at..]),
            None => (part, ""),
        };
        if name.is_empty()
            || !name
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
        {
            return Err(KeyError::BadName {
                part: part.to_owned(),
            });
        }
        steps.push(Step::Key(name.to_owned()));
        while !rest.is_empty() {
            let close = rest.find(']').ok_or_else(|| KeyError::Unclosed {
                part: part.to_owned(),
            })?;
            let index: usize = rest[1..close].parse().map_err(|_| KeyError::BadIndex {
                part: part.to_owned(),
                index: rest[1..close].to_owned(),
            })?;
            steps.push(Step::Index(index));
            rest = &rest[close + 1..];
            if !rest.is_empty() && !rest.starts_with('[') {
                return Err(KeyError::Trailing {
                    part: part.to_owned(),
                    rest: rest.to_owned(),
                });
            }
        }
    }
    Ok(steps)
}

/// Parses `value` as a TOML value, or takes it as a string.
fn parse_value(value: &str) -> Value {
    match format!("v = {value}").parse::<Table>() {
        Ok(mut table) => table
            .remove("v")
            .unwrap_or_else(|| Value::String(value.to_owned())),
        Err(_) => Value::String(value.to_owned()),
    }
}

/// Splits `KEY=VALUE`.
pub fn split_override(text: &str) -> Result<(&str, &str), OverrideError> {
    let (key, value) = text
        .split_once('=')
        .ok_or_else(|| OverrideError::Syntax(text.to_owned()))?;
    let (key, value) = (key.trim(), value.trim());
    if key.is_empty() || value.is_empty() {
        return Err(OverrideError::Syntax(text.to_owned()));
    }
    Ok((key, value))
}

/// Sets `key` (a dotted path with indices) to `value` in `table`.
pub fn set_value(table: &mut Table, key: &str, value: Value) -> Result<(), KeyError> {
    let steps = parse_path(key)?;
    let mut root = Value::Table(std::mem::take(table));
    let result = set_in(&mut root, &steps, value, key);
    if let Value::Table(root) = root {
        *table = root;
    }
    result
}

fn set_in(node: &mut Value, steps: &[Step], value: Value, key: &str) -> Result<(), KeyError> {
    let mut current: &mut Value = node;
    let mut walked = String::new();
    for (i, step) in steps.iter().enumerate() {
        let last = i + 1 == steps.len();
        match step {
            Step::Key(name) => {
                let Value::Table(table) = current else {
                    return Err(KeyError::NotATable {
                        walked,
                        name: name.clone(),
                    });
                };
                if !walked.is_empty() {
                    walked.push('.');
                }
                walked.push_str(name);
                if last {
                    table.insert(name.clone(), value);
                    return Ok(());
                }
                current = table
                    .entry(name.clone())
                    .or_insert_with(|| Value::Table(Table::new()));
            }
            Step::Index(index) => {
                let Value::Array(array) = current else {
                    return Err(KeyError::NotAnArray {
                        walked,
                        index: *index,
                    });
                };
                let len = array.len();
                let Some(slot) = array.get_mut(*index) else {
                    return Err(KeyError::OutOfRange {
                        walked,
                        index: *index,
                        len,
                    });
                };
                walked.push_str(&format!("[{index}]"));
                if last {
                    *slot = value;
                    return Ok(());
                }
                current = slot;
            }
        }
    }
    Err(KeyError::Empty {
        key: key.to_owned(),
    })
}

/// Applies `overrides` (`KEY=VALUE` each, in order) to scenario text; returns the new text.
pub fn apply_overrides(text: &str, overrides: &[String]) -> Result<String, OverrideError> {
    if overrides.is_empty() {
        return Ok(text.to_owned());
    }
    let mut table: Table = text.parse().map_err(|e: toml::de::Error| {
        OverrideError::Scenario(e.to_string().trim_end().to_owned())
    })?;
    for text in overrides {
        let (key, value) = split_override(text)?;
        set_value(&mut table, key, parse_value(value)).map_err(|problem| OverrideError::Key {
            text: text.clone(),
            problem,
        })?;
    }
    toml::to_string(&table).map_err(|e| OverrideError::Scenario(e.to_string()))
}

/// Splits a sweep's value list at its top-level commas: `200,500,1000` or `[0,1],[2,3]`.
pub fn split_values(list: &str) -> Vec<String> {
    let mut values = Vec::new();
    let mut depth = 0i32;
    let mut quoted = false;
    let mut current = String::new();
    for c in list.chars() {
        match c {
            '"' => quoted = !quoted,
            '[' | '{' if !quoted => depth += 1,
            ']' | '}' if !quoted => depth -= 1,
            ',' if !quoted && depth == 0 => {
                values.push(std::mem::take(&mut current).trim().to_owned());
                continue;
            }
            _ => {}
        }
        current.push(c);
    }
    values.push(current.trim().to_owned());
    values
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEXT: &str = r#"
duration_s = 0.5
k_n_per_m = 500.0

[[modes]]
kind = "surface"
transfer = [[0.45, 0.0], [0.5, 2.0]]

[[modes]]
kind = "friction"
mu = 0.5

[path]
kind = "line"
from_m = [0.0, 0.0, 0.045]
"#;

    fn set(overrides: &[&str]) -> Result<Table, OverrideError> {
        let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
        Ok(apply_overrides(TEXT, &overrides)?.parse().unwrap())
    }

    #[test]
    fn dotted_paths_and_indices_set_any_key() {
        let table = set(&[
            "k_n_per_m=200",
            "modes[1].mu=0.4",
            "modes[0].transfer[1][1]=3.0",
            "path.from_m=[0.0, 0.0, 0.05]",
            "solver.kind=euler",
            "rate_hz = 2e3",
        ])
        .unwrap();
        assert_eq!(table["k_n_per_m"].as_integer(), Some(200));
        assert_eq!(table["modes"][1]["mu"].as_float(), Some(0.4));
        assert_eq!(table["modes"][0]["transfer"][1][1].as_float(), Some(3.0));
        assert_eq!(table["path"]["from_m"][2].as_float(), Some(0.05));
        assert_eq!(table["solver"]["kind"].as_str(), Some("euler"));
        assert_eq!(table["rate_hz"].as_float(), Some(2000.0));
        // Untouched keys stay.
        assert_eq!(table["duration_s"].as_float(), Some(0.5));
    }

    #[test]
    fn bad_overrides_name_the_problem() {
        let err = set(&["k_n_per_m"]).unwrap_err().to_string();
        assert!(err.contains("KEY=VALUE"), "{err}");
        let err = set(&["modes[5].mu=1"]).unwrap_err().to_string();
        assert!(err.contains("modes has 2 elements"), "{err}");
        let err = set(&["k_n_per_m.x=1"]).unwrap_err().to_string();
        assert!(err.contains("k_n_per_m is not a table"), "{err}");
        let err = set(&["modes[x].mu=1"]).unwrap_err().to_string();
        assert!(err.contains("not an array index"), "{err}");
        let err = set(&["path[0]=1"]).unwrap_err().to_string();
        assert!(err.contains("path is not an array"), "{err}");
    }

    #[test]
    fn sweep_lists_split_at_top_level_commas() {
        assert_eq!(split_values("200,500, 1000"), ["200", "500", "1000"]);
        assert_eq!(
            split_values("[[0.4, 0.0], [0.5, 2.0]],[[0.4, 0.0], [0.5, 3.0]]"),
            ["[[0.4, 0.0], [0.5, 2.0]]", "[[0.4, 0.0], [0.5, 3.0]]"]
        );
        assert_eq!(split_values("\"a,b\",c"), ["\"a,b\"", "c"]);
    }
}
