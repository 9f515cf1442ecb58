//! A corpus of bad inputs made by mutating valid simulated data, and the runner that checks each
//! case's outcome against the `kincal` binary: the expected error (every listed substring in
//! stderr, non-zero exit) or the expected success, and in every case no panic, no hang, no file of
//! the user's lost or changed, no staging folder left behind, no non-finite figure printed.

use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// What a case must end in.
pub enum Expect {
    /// Exit non-zero with every substring in stderr (case-insensitive).
    Fails(Vec<String>),
    /// Exit 0, and the check (if any) holds on the case folder.
    Succeeds(Option<Check>),
    /// Either exit 0 with the check holding, or exit non-zero with one of the substrings in stderr
    /// (for seeded random mutations whose effect is not known in advance).
    Either(Vec<String>, Option<Check>),
}

/// A check on the case folder after a successful run.
pub type Check = Box<dyn Fn(&Path) -> Result<(), String> + Send + Sync>;
/// Mutation of the case folder before the run.
pub type Setup = Box<dyn Fn(&Path) + Send + Sync>;

/// One case: a mutated copy of the valid inputs, the command line, and the expected outcome.
pub struct Case {
    /// Unique name, `class/what`.
    pub name: String,
    /// Mutation applied to a fresh copy of the valid inputs.
    pub setup: Setup,
    /// Arguments of `kincal`, run in the case folder.
    pub args: Vec<String>,
    /// The outcome.
    pub expect: Expect,
    /// Largest file kincal may write, KiB (`ulimit -f` with SIGXFSZ ignored, so a larger write
    /// fails as on a full disk); `None`: no limit.
    pub max_file_kib: Option<u64>,
}

impl Case {
    /// A case expected to fail with `needles` in its message.
    pub fn fails(name: &str, setup: Setup, args: Vec<String>, needles: &[&str]) -> Case {
        Case {
            name: name.to_string(),
            setup,
            args,
            expect: Expect::Fails(needles.iter().map(|s| s.to_string()).collect()),
            max_file_kib: None,
        }
    }

    /// The same case on a "disk" that takes no file larger than `kib` KiB.
    pub fn with_disk_full_at(mut self, kib: u64) -> Case {
        self.max_file_kib = Some(kib);
        self
    }

    /// The same case with other command-line words.
    pub fn with_args(mut self, args: Vec<String>) -> Case {
        self.args = args;
        self
    }

    /// A case expected to succeed, with an optional check.
    pub fn succeeds(name: &str, setup: Setup, args: Vec<String>, check: Option<Check>) -> Case {
        Case { name: name.to_string(), setup, args, expect: Expect::Succeeds(check), max_file_kib: None }
    }
}

/// Command-line words from `base` followed by `extra`.
pub fn words(base: &[&str], extra: &[&str]) -> Vec<String> {
    base.iter().chain(extra).map(|s| s.to_string()).collect()
}

/// No mutation.
pub fn unchanged() -> Setup {
    Box::new(|_| {})
}

/// Replace `from` by `to` in the text file `file` (the text must be there).
pub fn replace(file: &str, from: &str, to: &str) -> Setup {
    let (file, from, to) = (file.to_string(), from.to_string(), to.to_string());
    Box::new(move |dir| {
        let path = dir.join(&file);
        let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(text.contains(&from), "{file} does not contain {from:?}");
        std::fs::write(&path, text.replacen(&from, &to, 1)).unwrap();
    })
}

/// Edit the JSON file `file` through `edit`.
pub fn edit_json(file: &str, edit: impl Fn(&mut Value) + Send + Sync + 'static) -> Setup {
    let file = file.to_string();
    Box::new(move |dir| {
        let path = dir.join(&file);
        let mut value: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        edit(&mut value);
        std::fs::write(&path, serde_json::to_string_pretty(&value).unwrap()).unwrap();
    })
}

/// Write `text` to `file` (creating folders).
pub fn write(file: &str, text: &str) -> Setup {
    let (file, text) = (file.to_string(), text.to_string());
    Box::new(move |dir| {
        let path = dir.join(&file);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, &text).unwrap();
    })
}

/// Run several setups in order.
pub fn all(setups: Vec<Setup>) -> Setup {
    Box::new(move |dir| setups.iter().for_each(|s| s(dir)))
}

/// Copy a folder tree.
pub fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.path().is_dir() {
            copy_tree(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

/// Every file under `dir` with its bytes, by path relative to `dir`.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<PathBuf, Vec<u8>>) {
        let Ok(entries) = std::fs::read_dir(dir) else { return };
        for entry in entries.flatten() {
            let path = entry.path();
            let Ok(kind) = entry.file_type() else { continue };
            let key = path.strip_prefix(root).unwrap().to_path_buf();
            if kind.is_dir() {
                walk(root, &path, out);
            } else if kind.is_symlink() {
                // A link is its target (never followed: it may lead to /dev/zero or to itself).
                let target = std::fs::read_link(&path).unwrap_or_default();
                out.insert(key, target.into_os_string().into_encoded_bytes());
            } else if kind.is_file() {
                if let Ok(bytes) = std::fs::read(&path) {
                    out.insert(key, bytes);
                }
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// Folders kincal wrote (they carry its marker): their files may be replaced.
fn kincal_folders(dir: &Path) -> Vec<PathBuf> {
    snapshot(dir)
        .keys()
        .filter(|p| p.file_name().is_some_and(|n| n == ".kincal-output"))
        .filter_map(|p| p.parent().map(Path::to_path_buf))
        .collect()
}

/// Pages kincal wrote (they may be replaced).
fn is_kincal_page(bytes: &[u8]) -> bool {
    String::from_utf8_lossy(&bytes[..bytes.len().min(4096)]).contains("<title>kincal")
}

/// Names of leftovers a failed or finished write must not leave: staging folders and temporaries.
fn leftovers(dir: &Path) -> Vec<String> {
    fn walk(dir: &Path, out: &mut Vec<String>) {
        let Ok(entries) = std::fs::read_dir(dir) else { return };
        for entry in entries.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            if name.contains(".partial-") || name.contains(".old-") || name.contains(".tmp-") {
                out.push(entry.path().display().to_string());
            }
            if entry.path().is_dir() {
                walk(&entry.path(), out);
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, &mut out);
    out
}

/// Run one prepared case in `dir`; `Err` says what went wrong.
fn run_case(bin: &Path, case: &Case, dir: &Path, logs: &Path, timeout: Duration) -> Result<(), String> {
    let before = snapshot(dir);
    let replaceable = kincal_folders(dir);
    let (out_path, err_path) = (logs.with_extension("out"), logs.with_extension("err"));
    let mut command = match case.max_file_kib {
        None => Command::new(bin),
        Some(kib) => {
            // An ignored SIGXFSZ is inherited across exec: writes past the limit fail with EFBIG.
            let mut sh = Command::new("sh");
            sh.arg("-c").arg(format!("trap '' XFSZ; ulimit -f {}; exec \"$0\" \"$@\"", kib * 2)).arg(bin);
            sh
        }
    };
    let mut child = command
        .args(&case.args)
        .current_dir(dir)
        .env("RUST_BACKTRACE", "0")
        .stdin(Stdio::null())
        .stdout(std::fs::File::create(&out_path).map_err(|e| e.to_string())?)
        .stderr(std::fs::File::create(&err_path).map_err(|e| e.to_string())?)
        .spawn()
        .map_err(|e| format!("cannot start kincal: {e}"))?;
    let started = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().map_err(|e| e.to_string())? {
            break status;
        }
        if started.elapsed() > timeout {
            let _ = child.kill();
            let _ = child.wait();
            return Err(format!("hang: still running after {} s", timeout.as_secs()));
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let stdout = std::fs::read_to_string(&out_path).unwrap_or_default();
    let stderr = std::fs::read_to_string(&err_path).unwrap_or_default();
    let shown = || format!("exit {:?}\nstdout: {}\nstderr: {}", status.code(), tail(&stdout), tail(&stderr));
    if stderr.contains("panicked") || status.code().is_none_or(|c| c != 0 && c != 1 && c != 2) {
        return Err(format!("panic or crash: {}", shown()));
    }
    let after = snapshot(dir);
    // A failed command changes nothing; a successful one may replace only what kincal wrote.
    let failed = !status.success();
    for (path, bytes) in &before {
        let may_replace =
            !failed && (replaceable.iter().any(|k| path.starts_with(k)) || is_kincal_page(bytes));
        if !may_replace && after.get(path) != Some(bytes) {
            return Err(format!("the user's file {} was lost or changed: {}", path.display(), shown()));
        }
    }
    let left = leftovers(dir);
    if !left.is_empty() {
        return Err(format!("left behind: {left:?}: {}", shown()));
    }
    let check_success = |check: &Option<Check>| -> Result<(), String> {
        for word in ["NaN", " inf", "-inf"] {
            if stdout.contains(word) {
                return Err(format!("success printed a non-finite figure ({word}): {}", shown()));
            }
        }
        match check {
            Some(check) => check(dir).map_err(|e| format!("{e}: {}", shown())),
            None => Ok(()),
        }
    };
    match &case.expect {
        Expect::Either(needles, check) => {
            if status.success() {
                return check_success(check);
            }
            let lower = stderr.to_lowercase();
            if !needles.iter().any(|n| lower.contains(&n.to_lowercase())) {
                return Err(format!("the error says none of {needles:?}: {}", shown()));
            }
        }
        Expect::Fails(needles) => {
            if status.success() {
                return Err(format!("expected an error, got success: {}", shown()));
            }
            // A failed command presents no figure as a result (the error may say why, on stderr).
            if ["calibration RMS ", "validation RMS "].iter().any(|w| stdout.contains(w)) {
                return Err(format!("a failed command printed a figure as a result: {}", shown()));
            }
            let lower = stderr.to_lowercase();
            if let Some(missing) = needles.iter().find(|n| !lower.contains(&n.to_lowercase())) {
                return Err(format!("the error does not say {missing:?}: {}", shown()));
            }
        }
        Expect::Succeeds(check) => {
            if !status.success() {
                return Err(format!("expected success: {}", shown()));
            }
            check_success(check)?;
        }
    }
    Ok(())
}

fn tail(text: &str) -> String {
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(12)..].join("\n")
}

/// Run every case on `threads` threads, each in a fresh copy of `template` under `work`;
/// returns the failures as `name: reason`.
pub fn run_corpus(
    bin: &Path,
    template: &Path,
    work: &Path,
    cases: &[Case],
    threads: usize,
    timeout: Duration,
) -> Vec<String> {
    let next = AtomicUsize::new(0);
    let failures = Mutex::new(Vec::new());
    let logs = work.join("logs");
    std::fs::create_dir_all(&logs).unwrap();
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::SeqCst);
                let Some(case) = cases.get(i) else { break };
                let dir = work.join(format!("case{i:04}"));
                copy_tree(template, &dir);
                (case.setup)(&dir);
                let log = logs.join(format!("case{i:04}"));
                match run_case(bin, case, &dir, &log, timeout) {
                    Ok(()) => {
                        let _ = std::fs::remove_dir_all(&dir);
                    }
                    Err(e) => {
                        failures.lock().unwrap().push(format!("{} ({}): {e}", case.name, dir.display()))
                    }
                }
            });
        }
    });
    failures.into_inner().unwrap()
}

/// Run `cases` (unique names asserted) on all cores, each in a fresh copy of `template` under
/// `work`, and panic with every failure.
pub fn assert_all_pass(bin: &Path, template: &Path, work: &Path, cases: &[Case], timeout: Duration) {
    let mut names: Vec<&str> = cases.iter().map(|c| c.name.as_str()).collect();
    names.sort_unstable();
    names.dedup();
    assert_eq!(names.len(), cases.len(), "case names must be unique");
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
    let started = Instant::now();
    let failures = run_corpus(bin, template, work, cases, threads, timeout);
    println!("{} cases in {:.1} s on {threads} threads", cases.len(), started.elapsed().as_secs_f64());
    assert!(
        failures.is_empty(),
        "{} of {} cases failed:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n\n")
    );
}
