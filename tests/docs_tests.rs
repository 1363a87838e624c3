//! The user-facing pages say what is true: the README's quick start is two commands, its
//! solver table names every registered solver with a page that exists, its links resolve, and
//! no page a user reads cites our issue tracker.

use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn read(rel: &str) -> String {
    std::fs::read_to_string(root().join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

/// The lines of the first fenced block after `heading`.
fn first_block_after(text: &str, heading: &str) -> Vec<String> {
    let after = &text[text.find(heading).unwrap_or_else(|| panic!("no {heading:?}"))..];
    let mut lines = after.lines().skip_while(|l| !l.starts_with("```")).skip(1);
    lines.by_ref().take_while(|l| !l.starts_with("```")).map(str::to_string).collect()
}

/// Markdown links `[text](target)` in `text`, local targets only (no scheme), anchors cut.
fn local_links(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for part in text.split("](").skip(1) {
        let target: String = part.chars().take_while(|c| *c != ')').collect();
        if target.contains("://") || target.starts_with('#') {
            continue;
        }
        out.push(target.split('#').next().unwrap().to_string());
    }
    out
}

#[test]
fn the_quick_start_is_the_two_commands_ci_runs() {
    let readme = read("README.md");
    let cmds = first_block_after(&readme, "## Quick start");
    assert_eq!(cmds.len(), 2, "the quick start is exactly two commands: {cmds:?}");
    assert!(cmds[0].starts_with("tools/scatterlab render scenes/default.toml"), "{}", cmds[0]);
    assert_eq!(cmds[1], "tools/test");
    // CI runs exactly the README's test command.
    let ci = read(".ci/run");
    assert!(ci.lines().any(|l| l.trim() == "tools/test" || l.trim().ends_with(" tools/test")), ".ci/run: {ci}");
    assert!(root().join("scenes/default.toml").is_file());
}

#[test]
fn the_solver_table_names_every_solver_with_its_page() {
    let readme = read("README.md");
    let table: Vec<&str> = readme
        .split("## The solvers")
        .nth(1)
        .and_then(|rest| rest.split("\n## ").next())
        .expect("a solvers section")
        .lines()
        .filter(|l| l.starts_with("| `"))
        .collect();
    let names: Vec<String> = table.iter().map(|l| l.split('`').nth(1).unwrap().to_string()).collect();
    let registry: Vec<String> = scatterlab::solvers::names().iter().map(|s| s.to_string()).collect();
    assert_eq!(names, registry, "the README's solver table, in registry order");
    for row in &table {
        let links = local_links(row);
        assert_eq!(links.len(), 1, "one docs link per row: {row}");
        assert!(root().join(&links[0]).is_file(), "{row}: {} is missing", links[0]);
    }
    // docs/solvers.md has a section for every solver (the README's anchors point there).
    let solvers = read("docs/solvers.md");
    for n in &registry {
        assert!(solvers.lines().any(|l| l == format!("## {n}")), "docs/solvers.md has no '## {n}'");
    }
}

#[test]
fn every_local_link_of_the_user_pages_resolves() {
    for page in ["README.md", "docs/usage.md", "docs/solvers.md", "docs/trade.md"] {
        let dir = root().join(page).parent().unwrap().to_path_buf();
        for link in local_links(&read(page)) {
            assert!(Path::new(&dir).join(&link).exists(), "{page}: link to {link} does not resolve");
        }
    }
}

#[test]
fn user_pages_do_not_cite_the_issue_tracker() {
    let pattern = |text: &str| -> Option<String> {
        let lower = text.to_lowercase();
        lower.match_indices("issue").find_map(|(i, _)| {
            let rest = lower[i + 5..].trim_start_matches([' ', '#']);
            rest.starts_with(|c: char| c.is_ascii_digit()).then(|| text[i..(i + 12).min(text.len())].to_string())
        })
    };
    for page in
        ["README.md", "docs/usage.md", "docs/solvers.md", "docs/trade.md", "docs/knobs.md", "docs/scene-format.md"]
    {
        if let Some(hit) = pattern(&read(page)) {
            panic!("{page} cites an issue number ({hit:?}): a user has no issue tracker");
        }
    }
    // Nor does the command line's help.
    let help =
        std::process::Command::new(env!("CARGO_BIN_EXE_scatterlab")).args(["render", "--help"]).output().unwrap();
    let text = String::from_utf8_lossy(&help.stdout);
    assert!(help.status.success() && pattern(&text).is_none(), "render --help: {text}");
}
