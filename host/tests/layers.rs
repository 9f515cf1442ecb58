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

/// The floors inside `calib`, lowest first: the engine's parts (errors, residual terms, block
/// unknowns, the problem, repeated touches, the setup, the bench problem's arm and sessions, which
/// read no other part of `calib`), identifiability, the fit, validation,
/// the noise floor; what is built on them (the diagnosis, outliers, the study, trust, the plan and
/// their checks); the run from input files to its summary. Modules of one floor may use each
/// other; none uses a floor above.
const CALIB_FLOORS: &[(&str, u8)] = &[
    ("error", 0),
    ("error_stats", 0),
    ("terms", 0),
    ("nuisance", 0),
    ("layout", 0),
    ("problem", 0),
    ("repeats", 0),
    ("setup", 0),
    ("bench_problem", 0),
    ("identify", 1),
    ("fit", 2),
    ("validate", 3),
    ("floor", 4),
    ("diagnose", 5),
    ("outliers", 5),
    ("study", 5),
    ("trust", 5),
    ("plan", 5),
    ("monte_carlo", 5),
    ("peer", 5),
    ("run", 6),
    ("summary", 6),
];

fn calib_floor(module: &str) -> Option<u8> {
    CALIB_FLOORS.iter().find(|(m, _)| *m == module).map(|(_, l)| *l)
}

/// The violations in one file of `calib`'s module `own`: `(line, used calib module)`.
fn calib_violations(own: &str, text: &str) -> Vec<(usize, String)> {
    let Some(own_floor) = calib_floor(own) else { return Vec::new() };
    let calib: Vec<(usize, String)> = text
        .lines()
        .enumerate()
        .flat_map(|(k, line)| {
            let code = line.split("//").next().unwrap_or("");
            code.match_indices("crate::calib::")
                .map(|(at, m)| {
                    let rest = &code[at + m.len()..];
                    (k + 1, rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect::<String>())
                })
                .collect::<Vec<_>>()
        })
        .collect();
    calib.into_iter().filter(|(_, used)| calib_floor(used).is_some_and(|f| f > own_floor)).collect()
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
        if file.file_name().is_some_and(|n| n == "tests.rs") {
            continue; // a module's unit tests may check it against anything above it
        }
        let text = std::fs::read_to_string(&file).unwrap();
        for (line, used) in violations(own, &text) {
            problems.push(format!("{}:{line}: `{own}` uses `{used}`", relative.display()));
        }
        if own == "calib" {
            let sub = relative.components().nth(1).map(|c| c.as_os_str().to_string_lossy().into_owned());
            let sub = sub.as_deref().unwrap_or("").trim_end_matches(".rs").to_string();
            if calib_floor(&sub).is_none() && sub != "mod" {
                problems.push(format!("{}: `calib::{sub}` has no floor in CALIB_FLOORS", relative.display()));
            }
            for (line, used) in calib_violations(&sub, &text) {
                problems.push(format!("{}:{line}: `calib::{sub}` uses `calib::{used}`", relative.display()));
            }
        }
    }
    assert!(checked > 40, "only {checked} source files found under {}", src.display());
    assert!(problems.is_empty(), "imports against the layers:\n{}", problems.join("\n"));
}

#[test]
fn the_check_catches_an_upward_import_inside_calib() {
    assert_eq!(
        calib_violations("fit", "use crate::calib::diagnose::Diagnosis;"),
        [(1, "diagnose".to_string())]
    );
    assert_eq!(calib_violations("diagnose", "x\nuse crate::calib::run::Run;"), [(2, "run".to_string())]);
    assert!(
        calib_violations("diagnose", "use crate::calib::fit::Fit; use crate::calib::study::x;").is_empty()
    );
    assert!(calib_violations("run", "use crate::calib::diagnose::Diagnosis;").is_empty());
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
