//! The library's layers (see `host/src/lib.rs`): a module may use only modules of a lower layer
//! (or itself). This test reads every source file and fails on an import that points upward or
//! sideways, e.g. `calib` using `report` or `controller`.

use std::path::{Path, PathBuf};

/// Top-level modules of the library and their layer, lowest first.
const LAYERS: &[(&str, u8)] = &[
    ("files", 0),
    ("numerics", 0),
    ("igtl", 0),
    ("trace", 1),
    ("model", 2),
    ("data", 3),
    ("simulate", 4),
    ("calib", 5),
    ("haptic", 5),
    ("motion", 5),
    ("report", 6),
    ("store", 7),
    ("api", 8),
    ("controller", 9),
];

fn layer(module: &str) -> Option<u8> {
    LAYERS.iter().find(|(m, _)| *m == module).map(|(_, l)| *l)
}

/// Every `crate::MODULE` a source text names, with its line number: plain paths, and the
/// top-level names of `crate::{…}` groups, also when a group spans lines or nests.
fn crate_references(text: &str) -> Vec<(usize, String)> {
    let code: String =
        text.lines().map(|l| l.split("//").next().unwrap_or("")).collect::<Vec<_>>().join("\n");
    let line_of = |at: usize| code[..at].matches('\n').count() + 1;
    let ident =
        |rest: &str| -> String { rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect() };
    let mut found = Vec::new();
    let mut from = 0;
    while let Some(offset) = code[from..].find("crate::") {
        let at = from + offset + "crate::".len();
        from = at;
        let rest = &code[at..];
        if !rest.starts_with('{') {
            found.push((line_of(at), ident(rest)));
            continue;
        }
        // Walk the group; a name right after `{` or a `,` at depth 1 is a top-level module.
        let mut depth = 0;
        let mut expect_name = false;
        for (k, c) in rest.char_indices() {
            match c {
                '{' => {
                    depth += 1;
                    expect_name = depth == 1;
                }
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        break;
                    }
                }
                ',' if depth == 1 => expect_name = true,
                c if expect_name && (c.is_alphanumeric() || c == '_') => {
                    found.push((line_of(at + k), ident(&rest[k..])));
                    expect_name = false;
                }
                _ => {}
            }
        }
    }
    found
}

/// The violations in one file of module `own`: `(line, used module)`.
fn violations(own: &str, text: &str) -> Vec<(usize, String)> {
    let Some(own_layer) = layer(own) else { return Vec::new() };
    crate_references(text)
        .into_iter()
        .filter(|(_, used)| used != own && layer(used).is_some_and(|l| l >= own_layer))
        .collect()
}

fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            sources(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

#[test]
fn no_module_imports_from_its_own_or_a_higher_layer() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    sources(&src, &mut files);
    let mut problems = Vec::new();
    let mut checked = 0;
    for file in files {
        let relative = file.strip_prefix(&src).unwrap();
        let first = relative.components().next().unwrap().as_os_str().to_string_lossy();
        let own = first.trim_end_matches(".rs");
        if layer(own).is_none() {
            continue; // lib.rs and the CLI (bin/) may use everything
        }
        checked += 1;
        let text = std::fs::read_to_string(&file).unwrap();
        for (line, used) in violations(own, &text) {
            problems.push(format!("{}:{line}: `{own}` uses `{used}`", relative.display()));
        }
    }
    assert!(checked > 40, "only {checked} source files found under {}", src.display());
    assert!(problems.is_empty(), "imports against the layers:\n{}", problems.join("\n"));
}

#[test]
fn the_check_catches_an_upward_and_a_sideways_import() {
    assert_eq!(violations("calib", "use crate::report::calibration;"), [(1, "report".to_string())]);
    assert_eq!(
        violations("calib", "use crate::{model::ArmModel, controller};\nlet x = crate::haptic::f();"),
        [(1, "controller".to_string()), (2, "haptic".to_string())]
    );
    assert!(violations("report", "use crate::calib::run::Run; // crate::output").is_empty());
    let multi_line = "use crate::{\n    model::{ArmModel, JOINTS},\n    report::svg,\n};";
    assert_eq!(violations("calib", multi_line), [(3, "report".to_string())]);
}
