//! The shell examples of the README and the book, run as a user would run them.
//!
//! A fenced block tagged `console` is an example: each line starting with `$ ` is a command (a
//! line ending in `\` continues it, and a here-document `<<'WORD'` runs to the line `WORD`); the
//! lines after it, up to the next command, are what it prints (stdout and stderr together). In
//! the shown output `[..]` stands for any text within a line (timings, keys, paths) and a line
//! `...` for any number of lines; a last line `[exit: N]` says the command exits with status N
//! (otherwise 0). A command shown without output is run and only its status checked.
//!
//! Every example of a page runs in order in one fresh, empty folder outside the repository, with
//! the `kincal` of this build first on `PATH`, in `bash`. A block tagged `console,emulator` needs
//! the emulated controller: those run in the emulator tests, with `$PORT` set to its port. Other
//! blocks (`text`, `sh`, …) are not run; the page says why where it matters.
//!
//! Own harness rather than `trycmd`: the examples are shell (`cd`, `&&`, variables, here-documents,
//! `$(mktemp -d)`), and the commands of one page build on each other's files, which `trycmd`
//! (one command per step, no shell) does not express.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Which examples a run takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Needs {
    /// `console`: nothing but `kincal`.
    Nothing,
    /// `console,emulator`: the emulated controller at `$PORT`.
    Emulator,
}

/// One command of an example and what it is shown to print.
#[derive(Clone, Debug)]
pub struct Step {
    /// Line of the command in its file (1-based).
    pub line: usize,
    /// The command as bash runs it.
    pub command: String,
    /// The shown output, `[exit: N]` removed.
    pub expected: Vec<String>,
    /// The exit status shown (0 unless `[exit: N]`).
    pub status: i32,
}

/// The examples of one markdown file that a run takes, in order.
#[derive(Debug)]
pub struct Page {
    /// The file, relative to the repository.
    pub file: PathBuf,
    /// Its commands, every block of the run's kind in order.
    pub steps: Vec<Step>,
}

/// The repository's root.
pub fn repository() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// README.md and every page of the book (`docs/src/**/*.md`), sorted.
pub fn markdown_files() -> Vec<PathBuf> {
    fn walk(dir: &Path, found: &mut Vec<PathBuf>) {
        let mut entries: Vec<PathBuf> =
            std::fs::read_dir(dir).map(|d| d.flatten().map(|e| e.path()).collect()).unwrap_or_default();
        entries.sort();
        for path in entries {
            if path.is_dir() {
                walk(&path, found);
            } else if path.extension().is_some_and(|e| e == "md") {
                found.push(path);
            }
        }
    }
    let root = repository();
    let mut files = vec![PathBuf::from("README.md")];
    let mut pages = Vec::new();
    walk(&root.join("docs/src"), &mut pages);
    files.extend(pages.into_iter().filter_map(|p| p.strip_prefix(&root).ok().map(Path::to_path_buf)));
    files
}

/// The pages with examples of kind `needs`.
pub fn pages(needs: Needs) -> Vec<Page> {
    markdown_files()
        .into_iter()
        .filter_map(|file| {
            let text = std::fs::read_to_string(repository().join(&file)).unwrap_or_default();
            let steps = steps_of(&text, needs);
            (!steps.is_empty()).then_some(Page { file, steps })
        })
        .collect()
}

/// The steps of the blocks of kind `needs` in a markdown text.
pub fn steps_of(text: &str, needs: Needs) -> Vec<Step> {
    let lines: Vec<&str> = text.lines().collect();
    let mut steps = Vec::new();
    let mut k = 0;
    while k < lines.len() {
        let fence = lines[k].trim_start();
        let tag = fence.strip_prefix("```").map(str::trim);
        k += 1;
        let kind = match tag {
            Some("console") => Needs::Nothing,
            Some("console,emulator") => Needs::Emulator,
            _ => continue,
        };
        let start = k;
        while k < lines.len() && !lines[k].trim_start().starts_with("```") {
            k += 1;
        }
        if kind == needs {
            steps.extend(parse_block(&lines[start..k], start + 1));
        }
        k += 1;
    }
    steps
}

/// The commands of one block whose first line is line `first` of its file.
fn parse_block(lines: &[&str], first: usize) -> Vec<Step> {
    let mut steps: Vec<Step> = Vec::new();
    let mut k = 0;
    while k < lines.len() {
        let Some(command) = lines[k].strip_prefix("$ ") else {
            if let Some(step) = steps.last_mut() {
                step.expected.push(lines[k].trim_end().to_string());
            }
            k += 1;
            continue;
        };
        let line = first + k;
        let mut command = command.to_string();
        while command.ends_with('\\') && k + 1 < lines.len() {
            k += 1;
            command.push('\n');
            command.push_str(lines[k]);
        }
        if let Some(word) = here_document_word(&command) {
            while k + 1 < lines.len() {
                k += 1;
                command.push('\n');
                command.push_str(lines[k]);
                if lines[k].trim() == word {
                    break;
                }
            }
        }
        steps.push(Step { line, command, expected: Vec::new(), status: 0 });
        k += 1;
    }
    for step in &mut steps {
        while step.expected.last().is_some_and(|l| l.is_empty()) {
            step.expected.pop();
        }
        if let Some(status) = step
            .expected
            .last()
            .and_then(|l| l.strip_prefix("[exit: "))
            .and_then(|l| l.strip_suffix(']'))
            .and_then(|n| n.parse().ok())
        {
            step.status = status;
            step.expected.pop();
            while step.expected.last().is_some_and(|l| l.is_empty()) {
                step.expected.pop();
            }
        }
    }
    steps
}

/// `WORD` of a here-document `<<'WORD'`, `<<"WORD"` or `<<WORD` in a command.
fn here_document_word(command: &str) -> Option<String> {
    let rest = &command[command.find("<<")? + 2..];
    let rest = rest.trim_start_matches('-').trim_start();
    let word: String = rest
        .trim_start_matches(['\'', '"'])
        .chars()
        .take_while(|c| c.is_alphanumeric() || *c == '_')
        .collect();
    (!word.is_empty()).then_some(word)
}

/// Whether `actual` is what `expected` shows: `[..]` within a line, `...` lines.
pub fn output_matches(expected: &[String], actual: &[String]) -> bool {
    match expected.split_first() {
        None => actual.is_empty(),
        Some((first, rest)) if first.trim() == "..." => {
            (0..=actual.len()).any(|skip| output_matches(rest, &actual[skip..]))
        }
        Some((first, rest)) => actual
            .split_first()
            .is_some_and(|(line, more)| line_matches(first, line) && output_matches(rest, more)),
    }
}

/// Whether `line` is what `pattern` shows, `[..]` standing for any text.
pub fn line_matches(pattern: &str, line: &str) -> bool {
    let parts: Vec<&str> = pattern.trim_end().split("[..]").collect();
    let line = line.trim_end();
    if parts.len() == 1 {
        return parts[0] == line;
    }
    let (first, last) = (parts[0], parts[parts.len() - 1]);
    if !line.starts_with(first) || line.len() < first.len() + last.len() || !line.ends_with(last) {
        return false;
    }
    let mut rest = &line[first.len()..line.len() - last.len()];
    for part in &parts[1..parts.len() - 1] {
        match rest.find(part) {
            Some(at) => rest = &rest[at + part.len()..],
            None => return false,
        }
    }
    true
}

/// Run every step of `page` in a fresh folder with `env` set; the failures, described.
pub fn run_page(page: &Page, kincal: &Path, env: &[(&str, &str)]) -> Vec<String> {
    let dir = std::env::temp_dir().join(format!(
        "kincal-docs-{}-{}",
        std::process::id(),
        page.file.to_string_lossy().replace(['/', '.'], "-")
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("a scratch folder");
    let bin = kincal.parent().expect("the binary's folder");
    let path = format!("{}:{}", bin.display(), std::env::var("PATH").unwrap_or_default());
    let mut failures = Vec::new();
    for step in &page.steps {
        let out = Command::new("bash")
            .arg("-c")
            .arg(format!("exec 2>&1\n{}", step.command))
            .current_dir(&dir)
            .env("PATH", &path)
            .envs(env.iter().copied())
            .output()
            .expect("bash runs");
        let text = String::from_utf8_lossy(&out.stdout);
        let actual: Vec<String> = text.lines().map(|l| l.trim_end().to_string()).collect();
        let status = out.status.code().unwrap_or(-1);
        let shown = step.expected.is_empty() || output_matches(&step.expected, &actual);
        if status != step.status || !shown {
            failures.push(format!(
                "{}:{}: `{}`\n  exit status {status} (shown: {}){}\n  --- printed ---\n{}",
                page.file.display(),
                step.line,
                step.command,
                step.status,
                if shown {
                    String::new()
                } else {
                    format!("\n  --- shown ---\n{}", step.expected.join("\n"))
                },
                actual.join("\n")
            ));
            break;
        }
    }
    if failures.is_empty() {
        let _ = std::fs::remove_dir_all(&dir);
    }
    failures
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(text: &str) -> Vec<String> {
        text.lines().map(String::from).collect()
    }

    #[test]
    fn placeholders_match_what_they_stand_for_and_nothing_else() {
        assert!(line_matches("took [..] s", "took 0.35 s"));
        assert!(line_matches("[..] mm", "0.150 mm"));
        assert!(line_matches("a [..] b [..] c", "a 1 b 2 c"));
        assert!(!line_matches("a [..] b [..] c", "a 1 c 2 b"));
        assert!(!line_matches("took [..] s", "took 0.35 ms!"));
        assert!(!line_matches("exact", "exact but longer"));
        assert!(output_matches(&lines("a\n...\nz"), &lines("a\nb\nc\nz")));
        assert!(output_matches(&lines("a\n...\nz"), &lines("a\nz")));
        assert!(!output_matches(&lines("a\n...\nz"), &lines("a\nb")));
        assert!(!output_matches(&lines("a\nb"), &lines("a\nb\nc")));
    }

    #[test]
    fn blocks_give_commands_their_output_continuations_and_here_documents() {
        let text = "```console\n$ kincal a \\\n    --b\nout 1\n\n[exit: 2]\n$ cat > f <<'EOF'\nx\nEOF\n```\n\
                    ```console,emulator\n$ kincal info --port $PORT\n```\n```text\n$ not run\n```\n";
        let steps = steps_of(text, Needs::Nothing);
        assert_eq!(steps.len(), 2);
        assert_eq!((steps[0].line, steps[0].command.as_str()), (2, "kincal a \\\n    --b"));
        assert_eq!((steps[0].expected.clone(), steps[0].status), (vec!["out 1".to_string()], 2));
        assert_eq!(steps[1].command, "cat > f <<'EOF'\nx\nEOF");
        assert!(steps[1].expected.is_empty());
        let emulated = steps_of(text, Needs::Emulator);
        assert_eq!(emulated.len(), 1);
        assert_eq!(emulated[0].command, "kincal info --port $PORT");
    }
}
