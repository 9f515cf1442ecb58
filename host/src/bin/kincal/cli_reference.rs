//! The CLI reference page of the book, `docs/src/reference/cli.md`, is every command's `--help`
//! rendered from the parser itself. The test fails when the committed page differs from what the
//! parser prints, and names the command that rewrites the page.

use super::Cli;
use clap::CommandFactory;
use std::path::PathBuf;

/// Rewrites the page instead of comparing when set (to any value).
const BLESS: &str = "KINCAL_BLESS";

fn page_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../docs/src/reference/cli.md")
}

/// The page: a heading and the long help of every command, depth first, in the parser's order.
fn render() -> String {
    let mut command = Cli::command();
    command.build();
    let mut page = String::from(
        "# Command-line reference\n\n\
         Every command's `--help`, generated from the parser. Do not edit this page by hand: a test\n\
         (`cargo test -p kincal --bin kincal cli_reference`) fails when it differs from what `kincal`\n\
         prints, and `KINCAL_BLESS=1 cargo test -p kincal --bin kincal cli_reference` rewrites it.\n",
    );
    visit(&mut command, &mut page);
    page
}

fn visit(command: &mut clap::Command, page: &mut String) {
    let name = command.get_bin_name().unwrap_or(command.get_name()).to_string();
    let help = command.render_long_help().to_string();
    let help: Vec<&str> = help.lines().map(str::trim_end).collect();
    page.push_str(&format!("\n## `{name}`\n\n```text\n{}\n```\n", help.join("\n").trim_end()));
    for sub in command.get_subcommands_mut().filter(|s| s.get_name() != "help") {
        visit(sub, page);
    }
}

#[test]
fn cli_reference_page_is_what_the_parser_prints() {
    let rendered = render();
    let path = page_path();
    if std::env::var_os(BLESS).is_some() {
        std::fs::write(&path, &rendered).unwrap();
        return;
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    if committed != rendered {
        let first = committed
            .lines()
            .zip(rendered.lines())
            .position(|(a, b)| a != b)
            .unwrap_or(committed.lines().count().min(rendered.lines().count()));
        panic!(
            "{} differs from the parser's --help texts (first at line {}:\n  page:   {:?}\n  parser: {:?}).\n\
             Rewrite it with: {BLESS}=1 cargo test -p kincal --bin kincal cli_reference",
            path.display(),
            first + 1,
            committed.lines().nth(first).unwrap_or("(end of page)"),
            rendered.lines().nth(first).unwrap_or("(end of page)"),
        );
    }
}
