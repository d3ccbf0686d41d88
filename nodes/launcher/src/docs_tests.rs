//! The README and docs/ name tests as the evidence of their claims: every test they name
//! must exist (a renamed or deleted test leaves a claim unbacked).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Every `fn name` in the workspace's Rust sources.
fn functions(dir: &Path, out: &mut BTreeSet<String>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if p.is_dir() && name != "target" && !name.starts_with('.') {
            functions(&p, out);
        } else if name.ends_with(".rs") {
            let text = std::fs::read_to_string(&p).unwrap_or_default();
            let mut rest = text.as_str();
            while let Some(i) = rest.find("fn ") {
                rest = &rest[i + 3..];
                let id: String = rest
                    .chars()
                    .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                    .collect();
                if !id.is_empty() {
                    out.insert(id);
                }
            }
        }
    }
}

/// Every Markdown file under `dir`, its subfolders included.
fn markdown(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            markdown(&p, out);
        } else if p.extension().and_then(|x| x.to_str()) == Some("md") {
            out.push(p);
        }
    }
}

/// Test names a document cites: `…tests::name`, and `e2e name` / `survive name` /
/// `two_way name` for the end-to-end tests.
fn cited(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let ident = |s: &str| -> String {
        s.chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect()
    };
    let mut rest = text;
    while let Some(i) = rest.find("tests::") {
        rest = &rest[i + 7..];
        out.push(ident(rest));
    }
    // a test of an integration-test file, named after the file's name (test names have an
    // underscore: "`contact over the run`" quotes a log line)
    for prefix in ["`e2e ", "`survive ", "`two_way ", "`contact ", "`hosts "] {
        let mut rest = text;
        while let Some(i) = rest.find(prefix) {
            rest = &rest[i + prefix.len()..];
            let name = ident(rest);
            if name.contains('_') {
                out.push(name);
            }
        }
    }
    out.retain(|n| !n.is_empty() && n != "tests");
    out
}

#[test]
fn every_test_the_docs_name_exists() {
    let root = repo();
    let mut fns = BTreeSet::new();
    for d in ["nodes", "messages", "tests"] {
        functions(&root.join(d), &mut fns);
    }
    let mut docs = vec![root.join("README.md")];
    markdown(&root.join("docs"), &mut docs);
    // the records of what was measured (docs/history/) cite tests too
    assert!(
        docs.iter()
            .any(|d| d.parent().is_some_and(|p| p.ends_with("history"))),
        "docs/history/ not read"
    );
    let mut checked = 0;
    let mut missing = Vec::new();
    for d in &docs {
        let text = std::fs::read_to_string(d).unwrap();
        for name in cited(&text) {
            checked += 1;
            if !fns.contains(&name) {
                missing.push(format!("{}: {name}", d.display()));
            }
        }
    }
    assert!(checked > 100, "only {checked} citations found");
    assert!(
        missing.is_empty(),
        "tests named in the docs that do not exist:\n{}",
        missing.join("\n")
    );
}

#[test]
fn citations_are_read_in_both_forms() {
    let c = cited(
        "test `dns slice::tests::a_b` and (`e2e c_d`, `survive e_f`); `contact over the run`",
    );
    assert_eq!(c, vec!["a_b", "c_d", "e_f"]);
}
