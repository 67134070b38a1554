//! The generated reference pages in docs/reference/: the CLI (from the clap definitions), the trace
//! columns and flags (from `voxhap::record`'s column list and flag table) and the scene file keys (from
//! `voxhap::sim::schema::SCENE_SCHEMA`, which its unit tests hold against the parser and validator).
//!
//! Where it sits: documentation checks. Each test renders its page from the code and fails when the committed
//! file differs, so the docs cannot drift from the flags or columns. `VOXHAP_BLESS=1 cargo test --test
//! integration docs_reference` writes the pages instead (after adding a flag or a column). The hand-written
//! protocol/VISUALISER.md is held to the keys the server sends by crates/server/src/messages_tests.rs.

use clap::CommandFactory;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Compares `generated` with the committed file `docs/reference/NAME`, or writes it when `VOXHAP_BLESS=1`.
fn check_or_bless(name: &str, generated: &str) {
    let path: PathBuf = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("docs/reference")
        .join(name);
    if std::env::var_os("VOXHAP_BLESS").is_some_and(|v| v == "1") {
        std::fs::write(&path, generated)
            .unwrap_or_else(|err| panic!("cannot write {}: {err}", path.display()));
        eprintln!("blessed {}", path.display());
        return;
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    if committed != generated {
        let first_difference = committed
            .lines()
            .zip(generated.lines())
            .position(|(a, b)| a != b)
            .unwrap_or_else(|| committed.lines().count().min(generated.lines().count()));
        panic!(
            "{} is stale (first difference at line {}): regenerate it with\n  \
             VOXHAP_BLESS=1 cargo test --test integration docs_reference\nand commit the result",
            path.display(),
            first_difference + 1
        );
    }
}

/// Hides the values of environment variables in help text (`--token` reads VOXHAP_TOKEN), so the page does
/// not depend on the environment the test runs in.
fn without_env_values(command: clap::Command) -> clap::Command {
    command
        .mut_args(|arg| arg.hide_env_values(true))
        .mut_subcommands(without_env_values)
}

fn render_command(out: &mut String, command: &mut clap::Command, path: &str) {
    let heading = if path.contains(' ') { "##" } else { "#" };
    if heading == "##" {
        writeln!(out, "{heading} `{path}`\n").unwrap();
    }
    let help = command.render_long_help().to_string();
    let help: Vec<&str> = help.trim_end().lines().map(str::trim_end).collect();
    writeln!(out, "```text\n$ {path} --help\n{}\n```\n", help.join("\n")).unwrap();
    let names: Vec<String> = command
        .get_subcommands()
        .filter(|sub| sub.get_name() != "help")
        .map(|sub| sub.get_name().to_owned())
        .collect();
    for name in names {
        let sub = command
            .find_subcommand_mut(&name)
            .expect("listed subcommand");
        render_command(out, sub, &format!("{path} {name}"));
    }
}

fn cli_markdown() -> String {
    let mut command = without_env_values(voxhap::cli::Cli::command());
    command.build();
    let mut out = String::from(
        "# The `voxhap` command-line reference\n\n\
         <!-- Generated from the clap definitions by tests/docs_reference.rs; do not edit by hand. After \
         changing a flag: VOXHAP_BLESS=1 cargo test --test integration docs_reference -->\n\n\
         Every subcommand's `--help`, as the binary prints it. Guides with examples: [serve](../serve.md), \
         [sim](../scenarios.md), [sims in CI](../sims.md), [traces](../traces.md), \
         [devices](../devices/README.md).\n\n",
    );
    out.push_str("Subcommands:");
    for sub in command.get_subcommands().filter(|s| s.get_name() != "help") {
        write!(out, " [`{0}`](#voxhap-{0}),", sub.get_name()).unwrap();
    }
    out.pop();
    out.push_str(".\n\n## `voxhap`\n\n");
    render_command(&mut out, &mut command, "voxhap");
    out.truncate(out.trim_end().len());
    out.push('\n');
    out
}

fn table_cell(text: &str) -> String {
    text.replace('|', "\\|")
}

fn trace_markdown() -> String {
    let mode = ["MODE".to_owned()];
    let mut out = String::from(
        "# Trace columns and flags\n\n\
         <!-- Generated from voxhap::record::columns and FLAG_DOCS by tests/docs_reference.rs; do not edit by \
         hand. After changing a column or a flag: VOXHAP_BLESS=1 cargo test --test integration docs_reference \
         -->\n\n\
         The columns of a CSV trace, in file order, as the sidecar's `columns` list gives them. The \
         per-mode columns repeat for every mode of the scene, `MODE` standing for the mode's name. How \
         traces are written, read and repaired: [Force traces](../traces.md).\n\n\
         ## Columns\n\n\
         | column | unit | type | meaning |\n|---|---|---|---|\n",
    );
    for column in voxhap::record::columns(&mode) {
        let column_type = serde_json::to_value(column.column_type).expect("column type serialises");
        writeln!(
            out,
            "| `{}` | {} | {} | {} |",
            column.name,
            column.unit,
            column_type.as_str().unwrap_or("?"),
            table_cell(&column.meaning)
        )
        .unwrap();
    }
    out.push_str(
        "\n## Flags\n\n\
         `flag_bits` holds every flag as one integer (bit `b` has the value `1 << b`); each flag also has its \
         own `true`/`false` column `flag_<name>`. The sidecar's `flag_bits` list repeats this table.\n\n\
         | bit | value | name | meaning |\n|---|---|---|---|\n",
    );
    for flag in voxhap::record::FLAG_DOCS.iter() {
        writeln!(
            out,
            "| {} | {} | `{}` | {} |",
            flag.bit,
            1u64 << flag.bit,
            flag.name,
            table_cell(&flag.meaning)
        )
        .unwrap();
    }
    out
}

fn scene_markdown() -> String {
    use voxhap::sim::schema::{KeyDefault, SCENE_SCHEMA};
    let mut out = String::from(
        "# Scene files\n\n\
         <!-- Generated from voxhap::sim::schema::SCENE_SCHEMA by tests/docs_reference.rs; do not edit by hand. \
         After changing a key: VOXHAP_BLESS=1 cargo test --test integration docs_reference -->\n\n\
         Every key of a scene file (`voxhap serve --scene FILE`) or scenario (`voxhap sim FILE`): one TOML \
         file, one schema, one validator. Units are SI and named in the key; unknown keys are errors, and \
         errors name the key (`solver.max_sweeps: must be from 1 to 10000000, got 0`). The unit tests of \
         `crates/servo/src/sim/schema.rs` hold this table against the parser and validator: each table's keys are the \
         ones the parser accepts, a default written out equals the key left out, each range is accepted at \
         its edges, and values just outside it, NaN and infinity are refused. Guides with examples: \
         [Scenarios](../scenarios.md), [Haptic modes](../modes.md), [The simulated arm](../sim-arm.md), \
         [Volumes](../volumes.md).\n",
    );
    for section in SCENE_SCHEMA {
        write!(
            out,
            "\n## {}\n\n{}\n\n| key | unit | default | accepts | meaning |\n|---|---|---|---|---|\n",
            section.title, section.intro
        )
        .unwrap();
        for key in section.keys {
            let default = match key.default {
                KeyDefault::Required => "required".to_owned(),
                KeyDefault::Value(value) => format!("`{value}`"),
                KeyDefault::Otherwise(words) => words.to_owned(),
            };
            writeln!(
                out,
                "| `{}` | {} | {} | {} | {} |",
                key.name,
                if key.unit.is_empty() { "-" } else { key.unit },
                table_cell(&default),
                table_cell(&key.accepts.describe()),
                table_cell(key.meaning)
            )
            .unwrap();
        }
    }
    out
}

#[test]
fn scene_reference_matches_the_schema_table() {
    let page = scene_markdown();
    assert!(
        page.contains("| `tolerance_m` | m | `1e-12` | 1e-18 to 1e-3 |"),
        "{page}"
    );
    check_or_bless("scene.md", &page);
}

#[test]
fn cli_reference_matches_the_clap_definitions() {
    check_or_bless("cli.md", &cli_markdown());
}

#[test]
fn trace_reference_matches_the_column_list_and_flag_table() {
    let page = trace_markdown();
    // Every flag of the code is on the page, bit 7 included (it was once missing from the hand-written list).
    assert!(
        page.contains("| 7 | 128 | `compute_over_budget` |"),
        "{page}"
    );
    check_or_bless("trace.md", &page);
}

/// The text between `<!-- solver-bench:NAME begin -->` and `<!-- solver-bench:NAME end -->` in a file of the
/// crate (benches/solver.rs writes it with `VOXHAP_BENCH_DOCS=1`).
fn bench_block(path: &str, name: &str) -> String {
    let full = Path::new(env!("CARGO_MANIFEST_DIR")).join(path);
    let text = std::fs::read_to_string(&full)
        .unwrap_or_else(|err| panic!("cannot read {}: {err}", full.display()));
    let begin = format!("<!-- solver-bench:{name} begin -->\n");
    let end = format!("<!-- solver-bench:{name} end -->");
    let start = text
        .find(&begin)
        .unwrap_or_else(|| panic!("{path}: no marker {}", begin.trim()))
        + begin.len();
    let stop = text[start..]
        .find(&end)
        .unwrap_or_else(|| panic!("{path}: no marker {end}"))
        + start;
    text[start..stop].to_owned()
}

/// A printed time (`99 ns`, `5.5 us`, `1.06 ms`) in ns, and half its last printed digit (the rounding).
fn printed_ns(cell: &str) -> (f64, f64) {
    let (number, unit) = cell
        .trim()
        .split_once(' ')
        .unwrap_or_else(|| panic!("not a time: {cell:?}"));
    let scale = match unit {
        "ns" => 1.0,
        "us" => 1e3,
        "ms" => 1e6,
        _ => panic!("unknown unit in {cell:?}"),
    };
    let decimals = number.split_once('.').map_or(0, |(_, d)| d.len());
    let value: f64 = number
        .parse()
        .unwrap_or_else(|_| panic!("not a number: {cell:?}"));
    (value * scale, 0.5 * 10f64.powi(-(decimals as i32)) * scale)
}

/// The table rows (cells trimmed) after the header line `header` in a bench block.
fn bench_rows<'a>(block: &'a str, header: &str) -> Vec<Vec<&'a str>> {
    let mut lines = block.lines().skip_while(|l| !l.starts_with(header));
    assert!(
        lines.next().is_some(),
        "no table headed {header:?} in:\n{block}"
    );
    lines
        .skip(1)
        .take_while(|l| l.starts_with('|'))
        .map(|l| l.trim_matches('|').split('|').map(str::trim).collect())
        .collect()
}

#[test]
fn solver_tables_are_the_benchmarks_output() {
    let bench_source =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/solver.rs"))
            .expect("benches/solver.rs");
    let summary_header = bench_source
        .lines()
        .find_map(|l| {
            l.strip_prefix("const SUMMARY_HEADER: &str = \"")?
                .strip_suffix("\";")
        })
        .expect("benches/solver.rs defines SUMMARY_HEADER");
    let full_header = "| case | exact | exact error | exact bound |";
    assert!(bench_source.contains(full_header));

    let readme = bench_block("README.md", "summary");
    let summary = bench_block("docs/solver.md", "summary");
    let full = bench_block("docs/solver.md", "full");
    assert_eq!(
        readme, summary,
        "README.md and docs/solver.md hold different summary tables; both are written by one run of \
         VOXHAP_BENCH_DOCS=1 cargo bench --bench solver"
    );
    // One run: the same title (machine and date) on both tables.
    let title = summary
        .lines()
        .nth(1)
        .expect("a title line after the fence");
    assert!(
        title.starts_with("Solver benchmark (cargo bench --bench solver): ")
            && title.ends_with(" UTC"),
        "not the bench's title: {title:?}"
    );
    assert_eq!(
        full.lines().nth(1),
        Some(title),
        "the full table is from another run"
    );

    let cases = [
        "exploration path (per tick, worst tick)",
        "wedge 5 degrees",
        "wedge 1 degrees",
        "10 random primitives",
        "100 random primitives",
        "1000 random primitives",
        "3000 mixed primitives",
        "10000 mixed primitives",
    ];
    let rows = bench_rows(&summary, summary_header);
    let full_rows = bench_rows(&full, full_header);
    assert_eq!(rows.iter().map(|r| r[0]).collect::<Vec<_>>(), cases);
    assert_eq!(full_rows.iter().map(|r| r[0]).collect::<Vec<_>>(), cases);
    let mut goals = 0;
    for (row, full_row) in rows.iter().zip(&full_rows) {
        assert_eq!(row.len(), 11, "{row:?}");
        // The summary repeats the full table's cells for the exact solver and for Euler at both stops.
        assert_eq!((row[1], row[2]), (full_row[1], full_row[3]), "{}", row[0]);
        assert_eq!(&row[3..6], &full_row[8..11], "{}", row[0]);
        assert_eq!(&row[6..9], &full_row[11..14], "{}", row[0]);
        let (exact, exact_rounding) = printed_ns(row[1]);
        // Each speed-up is Euler's time over the exact solver's, up to the rounding of the printed times.
        for (time, speed_up) in [(row[3], row[5]), (row[6], row[8])] {
            let (other, other_rounding) = printed_ns(time);
            let printed: f64 = speed_up
                .strip_suffix('x')
                .and_then(|v| v.parse().ok())
                .unwrap_or_else(|| panic!("{}: not a speed-up: {speed_up:?}", row[0]));
            let low = (other - other_rounding) / (exact + exact_rounding) - 0.005;
            let high = (other + other_rounding) / (exact - exact_rounding) + 0.005;
            assert!(
                (low..=high).contains(&printed),
                "{}: speed-up {speed_up} is not {time} over {}",
                row[0],
                row[1]
            );
        }
        if row[9] == "-" {
            assert_eq!(row[10], "-", "{}", row[0]);
            continue;
        }
        goals += 1;
        let goal = printed_ns(row[9].strip_prefix("< ").expect("a goal `< T`")).0;
        assert!(
            row[10] == "yes" || row[10] == "no",
            "{}: met is {:?}",
            row[0],
            row[10]
        );
        if (exact - goal).abs() > exact_rounding {
            assert_eq!(
                row[10] == "yes",
                exact < goal,
                "{}: {} against the goal {} is marked met = {}",
                row[0],
                row[1],
                row[9],
                row[10]
            );
        }
    }
    assert_eq!(goals, 5, "the solver has speed goals for five cases");
}
