//! Every `console` example of the README and the book runs and prints what it shows (see
//! `kincal_e2e::doc_examples`); the `console,emulator` ones run in `emulated_controller.rs`.

use kincal_e2e::doc_examples::{pages, run_page, Needs};
use kincal_e2e::kincal_bin;

#[test]
fn every_example_of_the_readme_and_the_book_prints_what_it_shows() {
    let pages = pages(Needs::Nothing);
    let steps: usize = pages.iter().map(|p| p.steps.len()).sum();
    assert!(pages.iter().any(|p| p.file.ends_with("README.md")), "the README shows no example");
    assert!(steps >= 10, "only {steps} examples found: the `console` blocks went missing");
    let kincal = kincal_bin();
    let failures: Vec<String> = std::thread::scope(|scope| {
        let runs: Vec<_> = pages.iter().map(|page| scope.spawn(|| run_page(page, &kincal, &[]))).collect();
        runs.into_iter().flat_map(|run| run.join().expect("a page's examples ran")).collect()
    });
    assert!(
        failures.is_empty(),
        "{} of {} pages' examples differ:\n\n{}",
        failures.len(),
        pages.len(),
        failures.join("\n\n")
    );
}
