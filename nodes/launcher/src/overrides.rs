//! The launch file as TOML before it is typed: `--set` overrides, and keys that were
//! renamed or belong elsewhere (each an error naming the key to use).

use anyhow::{bail, Result};

/// Applies `--set KEY=VALUE` overrides to a parsed launch file. KEY is a dotted path
/// (`run.steps`, `flow.source.dns.nx`); inside `[[fibers]]` a segment is an index or a
/// group name (`fibers.case1.count`). VALUE is a TOML value; a bare word is a string.
pub fn apply_overrides(doc: &mut toml::Table, sets: &[String]) -> Result<()> {
    for set in sets {
        let Some((key, raw)) = set.split_once('=') else {
            bail!("--set {set:?}: expected KEY=VALUE, e.g. --set run.steps=400");
        };
        let (key, raw) = (key.trim(), raw.trim());
        let value = match toml::from_str::<toml::Table>(&format!("v = {raw}")) {
            Ok(mut t) => t
                .remove("v")
                .unwrap_or_else(|| toml::Value::String(raw.into())),
            Err(_) if !raw.is_empty() && !raw.contains(['"', '\'', '[', '{']) => {
                toml::Value::String(raw.into())
            }
            Err(e) => bail!("--set {key}: {raw:?} is not a TOML value: {e}"),
        };
        let parts: Vec<&str> = key.split('.').collect();
        if key.is_empty() || parts.iter().any(|p| p.is_empty()) {
            bail!("--set {set:?}: the key must be a dotted path such as run.steps");
        }
        set_path(doc, &parts, key, value)?;
    }
    Ok(())
}

fn set_path(table: &mut toml::Table, parts: &[&str], key: &str, value: toml::Value) -> Result<()> {
    let (head, rest) = (parts[0], &parts[1..]);
    if rest.is_empty() {
        table.insert(head.to_string(), value);
        return Ok(());
    }
    let entry = table.entry(head.to_string()).or_insert_with(|| {
        let mut t = toml::Table::new();
        // a group without a placement table has the default one: setting one of its
        // keys (e.g. placement.per_layer) keeps that kind
        if head == "placement" {
            t.insert("kind".into(), toml::Value::String("layers".into()));
        }
        toml::Value::Table(t)
    });
    match entry {
        toml::Value::Table(t) => set_path(t, rest, key, value),
        toml::Value::Array(items) => {
            let sel = rest[0];
            let idx = sel.parse::<usize>().ok().or_else(|| {
                items
                    .iter()
                    .position(|it| it.get("group").and_then(|g| g.as_str()) == Some(sel))
            });
            let Some(toml::Value::Table(item)) = idx.and_then(|n| items.get_mut(n)) else {
                bail!("--set {key}: {head} has no entry {sel:?} (use an index or a group name)");
            };
            if rest.len() < 2 {
                bail!("--set {key}: name a key inside {head}.{sel}");
            }
            set_path(item, &rest[1..], key, value)
        }
        _ => bail!("--set {key}: {head} is a value, not a table"),
    }
}

/// Keys that were renamed, as (table, old key, new key): user-facing keys spell "fiber",
/// as `[[fibers]]` does, and every interval key names its unit (`_steps` or `_plus`). The
/// old name is an error that names the new one. `fibers[]` stands for every `[[fibers]]`.
const RENAMED_KEYS: [(&str, &str, &str); 8] = [
    ("run", "fibre_processes", "fiber_processes"),
    ("run", "fibre_scheduling", "fiber_scheduling"),
    ("flow", "status_every", "status_every_steps"),
    ("flow", "profiles_every", "profiles_every_steps"),
    ("flow", "slices_every", "slices_every_steps"),
    ("flow.source.dns", "check_every", "check_every_steps"),
    ("fibers[]", "metrics_every", "metrics_every_steps"),
    ("recorder", "states_every", "states_every_steps"),
];

/// The tables at `path` (dot-separated; `name[]` is every table of an array of tables).
fn tables_at<'a>(doc: &'a toml::Table, path: &str) -> Vec<&'a toml::Table> {
    let mut found = vec![doc];
    for part in path.split('.') {
        let (name, array) = match part.strip_suffix("[]") {
            Some(name) => (name, true),
            None => (part, false),
        };
        found = found
            .into_iter()
            .filter_map(|t| t.get(name))
            .flat_map(|v| -> Vec<&toml::Table> {
                match (array, v) {
                    (true, toml::Value::Array(items)) => {
                        items.iter().filter_map(toml::Value::as_table).collect()
                    }
                    (false, toml::Value::Table(t)) => vec![t],
                    _ => vec![],
                }
            })
            .collect();
    }
    found
}

/// Keys a launch file must not have, each an error that names the key to use instead:
/// renamed keys ([`RENAMED_KEYS`]), and `flow.steps` / `flow.dt_plus` / `flow.realisation`,
/// the flow node's own keys, which a launch file sets from `run.steps` / `run.dt_plus` /
/// `run.realisation` (a value under `[flow]` would be silently replaced).
pub(crate) fn refuse_misplaced_keys(text: &str) -> Result<()> {
    // a file that is not TOML gets its error, with the file's name, from the parse after
    let Ok(doc) = toml::from_str::<toml::Table>(text) else {
        return Ok(());
    };
    let table = |name: &str| doc.get(name).and_then(toml::Value::as_table);
    if let Some(flow) = table("flow") {
        for (key, instead) in [
            ("steps", "run.steps"),
            ("dt_plus", "run.dt_plus"),
            ("realisation", "run.realisation"),
        ] {
            if flow.contains_key(key) {
                bail!("flow.{key} is set from {instead} in a launch file: remove flow.{key} and set {instead}");
            }
        }
    }
    for (path, old, new) in RENAMED_KEYS {
        if tables_at(&doc, path).iter().any(|t| t.contains_key(old)) {
            bail!("{path}.{old} was renamed: use {path}.{new}");
        }
    }
    Ok(())
}
