//! Every relative link in the documentation resolves: README.md, ARCHITECTURE.md and every Markdown page
//! under docs/ (and the files those pages include), to a file or folder inside the repository (inside docs/
//! for a docs/ page, since the book holds only docs/) and, when the link has a `#fragment`, to a heading (or
//! an `<a id>`) of the Markdown file it names. Every page under docs/ is listed in docs/SUMMARY.md.
//!
//! Where it sits: documentation checks, beside tests/docs_reference.rs. Heading anchors follow the rule GitHub
//! and mdBook share: lower case, letters, digits, `-` and `_` kept, spaces become `-`, everything else is
//! dropped, and a repeated heading gets `-1`, `-2`, ... Web links (`https://...`) are not fetched.

use std::collections::BTreeSet;
use std::path::{Component, Path, PathBuf};

fn repository_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The lines of a Markdown file outside fenced code blocks, with their 1-based numbers.
fn prose_lines(text: &str) -> Vec<(usize, &str)> {
    let mut fence: Option<&str> = None;
    let mut lines = Vec::new();
    for (index, line) in text.lines().enumerate() {
        let trimmed = line.trim_start();
        let marker = if trimmed.starts_with("```") {
            Some("```")
        } else if trimmed.starts_with("~~~") {
            Some("~~~")
        } else {
            None
        };
        match (fence, marker) {
            (None, Some(m)) => fence = Some(m),
            (Some(open), Some(m)) if open == m => fence = None,
            (None, None) => lines.push((index + 1, line)),
            _ => {}
        }
    }
    lines
}

/// `line` with inline code spans (`` `...` ``) and HTML comments (`<!-- ... -->`, on one line) removed.
fn without_code_spans(line: &str) -> String {
    let mut uncommented = String::with_capacity(line.len());
    let mut rest = line;
    while let Some(start) = rest.find("<!--") {
        uncommented.push_str(&rest[..start]);
        rest = match rest[start..].find("-->") {
            Some(end) => &rest[start + end + 3..],
            None => "",
        };
    }
    uncommented.push_str(rest);
    let mut out = String::with_capacity(line.len());
    let mut in_code = false;
    for ch in uncommented.chars() {
        if ch == '`' {
            in_code = !in_code;
        } else if !in_code {
            out.push(ch);
        }
    }
    out
}

/// The targets of inline links `[text](target)` and reference definitions `[label]: target` in a line.
fn link_targets(line: &str) -> Vec<String> {
    let line = without_code_spans(line);
    let mut targets = Vec::new();
    let trimmed = line.trim_start();
    if trimmed.starts_with('[') {
        if let Some(end) = trimmed.find("]:") {
            let target = trimmed[end + 2..].split_whitespace().next().unwrap_or("");
            targets.push(target.trim_matches(['<', '>']).to_owned());
        }
    }
    let mut rest = line.as_str();
    while let Some(start) = rest.find("](") {
        let after = &rest[start + 2..];
        let mut depth = 0usize;
        let mut end = after.len();
        for (i, ch) in after.char_indices() {
            match ch {
                '(' => depth += 1,
                ')' if depth == 0 => {
                    end = i;
                    break;
                }
                ')' => depth -= 1,
                _ => {}
            }
        }
        let inside = after[..end].trim();
        let target = inside.split_whitespace().next().unwrap_or("");
        targets.push(target.trim_matches(['<', '>']).to_owned());
        rest = &after[end.min(after.len())..];
    }
    targets
}

/// The anchor a heading gets (GitHub and mdBook): see the module header.
fn slug(heading: &str) -> String {
    let mut text = String::new();
    // Link text only: `[text](url)` -> `text`.
    let mut rest = heading;
    while let Some(open) = rest.find('[') {
        match rest[open..].find("](") {
            Some(mid) => {
                let close = rest[open + mid..].find(')').map(|c| open + mid + c);
                text.push_str(&rest[..open]);
                text.push_str(&rest[open + 1..open + mid]);
                rest = match close {
                    Some(c) => &rest[c + 1..],
                    None => "",
                };
            }
            None => break,
        }
    }
    text.push_str(rest);
    text.chars()
        .filter_map(|ch| {
            if ch.is_alphanumeric() || ch == '_' || ch == '-' {
                Some(ch.to_lowercase().collect::<String>())
            } else if ch == ' ' {
                Some("-".to_owned())
            } else {
                None
            }
        })
        .collect()
}

/// Every anchor a Markdown file offers: its headings' slugs and its `<a id="...">`/`<a name="...">` tags.
fn anchors(text: &str) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    for (_, line) in prose_lines(text) {
        let trimmed = line.trim_start();
        let hashes = trimmed.chars().take_while(|&c| c == '#').count();
        if (1..=6).contains(&hashes) && trimmed[hashes..].starts_with(' ') {
            let base = slug(trimmed[hashes..].trim().trim_end_matches('#').trim());
            let mut anchor = base.clone();
            let mut n = 0;
            while found.contains(&anchor) {
                n += 1;
                anchor = format!("{base}-{n}");
            }
            found.insert(anchor);
        }
        for key in ["<a id=\"", "<a name=\""] {
            let mut rest = line;
            while let Some(start) = rest.find(key) {
                let after = &rest[start + key.len()..];
                if let Some(end) = after.find('"') {
                    found.insert(after[..end].to_owned());
                }
                rest = after;
            }
        }
    }
    found
}

/// `path` without `.` and `..` components (no file system access, so links to missing files still resolve).
fn normalise(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for component in path.components() {
        match component {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            other => out.push(other),
        }
    }
    out
}

/// The Markdown files to check: README.md, ARCHITECTURE.md, docs/**/*.md and what their `{{#include}}`s
/// name.
fn documentation_files(root: &Path) -> Vec<PathBuf> {
    let mut files = vec![root.join("README.md"), root.join("ARCHITECTURE.md")];
    let mut folders = vec![root.join("docs")];
    while let Some(folder) = folders.pop() {
        let entries = std::fs::read_dir(&folder)
            .unwrap_or_else(|err| panic!("cannot list {}: {err}", folder.display()));
        for entry in entries {
            let path = entry.expect("directory entry").path();
            if path.is_dir() {
                folders.push(path);
            } else if path.extension().is_some_and(|e| e == "md") {
                files.push(path);
            }
        }
    }
    let mut included = Vec::new();
    for file in &files {
        let text = std::fs::read_to_string(file).expect("readable page");
        for line in text.lines() {
            if let Some(rest) = line.trim().strip_prefix("{{#include ") {
                let target = rest.trim_end_matches("}}").trim();
                let target = target.split(':').next().unwrap_or(target);
                included.push(normalise(&file.parent().expect("in a folder").join(target)));
            }
        }
    }
    files.extend(included);
    files.sort();
    files.dedup();
    files
}

/// The problems with one file's links, as `file:line: target: problem`.
fn check_file(root: &Path, file: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(file)
        .unwrap_or_else(|err| panic!("cannot read {}: {err}", file.display()));
    let shown = file
        .strip_prefix(root)
        .unwrap_or(file)
        .display()
        .to_string();
    let mut problems = Vec::new();
    for (number, line) in prose_lines(&text) {
        for target in link_targets(line) {
            if target.is_empty()
                || target.contains("://")
                || target.starts_with("mailto:")
                || target.starts_with("{{")
            {
                continue;
            }
            let (path_part, fragment) = match target.split_once('#') {
                Some((p, f)) => (p, Some(f)),
                None => (target.as_str(), None),
            };
            let resolved = if path_part.is_empty() {
                file.to_path_buf()
            } else {
                normalise(&file.parent().expect("in a folder").join(path_part))
            };
            let problem = if !resolved.starts_with(root) {
                Some("points outside the repository".to_owned())
            } else if file.starts_with(root.join("docs"))
                && !resolved.starts_with(root.join("docs"))
            {
                Some(
                    "points outside docs/, which the book cannot show (link a docs/ page instead, e.g. \
                     protocol-spec.md, which includes protocol/SPEC.md)"
                        .to_owned(),
                )
            } else if !resolved.exists() {
                Some(format!(
                    "{} does not exist",
                    resolved.strip_prefix(root).unwrap_or(&resolved).display()
                ))
            } else if let Some(fragment) = fragment {
                if resolved.extension().is_some_and(|e| e == "md") {
                    let target_text = std::fs::read_to_string(&resolved).expect("readable page");
                    let offered = anchors(&target_text);
                    (!offered.contains(fragment)).then(|| {
                        format!(
                            "no heading with anchor #{fragment} in {}",
                            resolved.strip_prefix(root).unwrap_or(&resolved).display()
                        )
                    })
                } else {
                    None
                }
            } else {
                None
            };
            if let Some(problem) = problem {
                problems.push(format!("{shown}:{number}: {target}: {problem}"));
            }
        }
    }
    problems
}

#[test]
fn every_relative_link_and_anchor_in_the_docs_resolves() {
    let root = repository_root();
    let files = documentation_files(&root);
    assert!(
        files.len() > 10,
        "expected the README and the docs pages, found {files:?}"
    );
    let problems: Vec<String> = files.iter().flat_map(|f| check_file(&root, f)).collect();
    assert!(
        problems.is_empty(),
        "{} broken link(s):\n{}",
        problems.len(),
        problems.join("\n")
    );
}

#[test]
fn every_docs_page_is_in_the_book_summary() {
    let root = repository_root();
    let docs = root.join("docs");
    let summary_text = std::fs::read_to_string(docs.join("SUMMARY.md")).expect("docs/SUMMARY.md");
    let listed: BTreeSet<PathBuf> = prose_lines(&summary_text)
        .into_iter()
        .flat_map(|(_, line)| link_targets(line))
        .map(|target| normalise(&docs.join(target)))
        .collect();
    let missing: Vec<String> = documentation_files(&root)
        .into_iter()
        .filter(|file| {
            file.starts_with(&docs) && !file.ends_with("SUMMARY.md") && !listed.contains(file)
        })
        .map(|file| {
            file.strip_prefix(&root)
                .unwrap_or(&file)
                .display()
                .to_string()
        })
        .collect();
    assert!(
        missing.is_empty(),
        "pages not listed in docs/SUMMARY.md (the book would leave them out): {missing:?}"
    );
}

#[test]
fn anchors_follow_the_github_and_mdbook_rule() {
    let page =
        "# `voxhap serve`\n## Real-time setup\n```\n# not a heading\n```\n## Real-time setup\n\
                ## 1. Start voxhap with the [OpenIGTLink](x.md) server\n";
    let found = anchors(page);
    let expected: BTreeSet<String> = [
        "voxhap-serve",
        "real-time-setup",
        "real-time-setup-1",
        "1-start-voxhap-with-the-openigtlink-server",
    ]
    .into_iter()
    .map(String::from)
    .collect();
    assert_eq!(found, expected);
}

#[test]
fn a_broken_link_and_a_missing_anchor_are_reported() {
    let folder = tempfile::tempdir().expect("temporary folder");
    let root = folder.path();
    std::fs::write(root.join("b.md"), "# Here\n").unwrap();
    std::fs::write(
        root.join("a.md"),
        "[ok](b.md#here) [gone](c.md) [bad anchor](b.md#there) `[code](c.md)` <!-- [comment](c.md) -->\n\
         ```\n[fenced](c.md)\n```\n",
    )
    .unwrap();
    let problems = check_file(root, &root.join("a.md"));
    assert_eq!(problems.len(), 2, "{problems:?}");
    assert!(problems[0].contains("c.md does not exist"), "{problems:?}");
    assert!(
        problems[1].contains("no heading with anchor #there"),
        "{problems:?}"
    );
}
