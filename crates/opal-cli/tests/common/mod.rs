//! Helpers shared by the CLI integration tests: the key-set check of `--json` outputs against
//! the documented schema.

use serde_json::Value;
use std::collections::BTreeSet;
use std::path::Path;

/// The text of `docs/<name>`.
pub fn doc(name: &str) -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs").join(name)).unwrap()
}

/// `v` is an object with exactly the keys `want`, each of which `page` (under docs/) names (as
/// `key`, "key", as an item of a `{key, …}` list, or as `key {…}` / `key […]`).
pub fn assert_keys(what: &str, v: &Value, want: &[&str], page: &str) {
    let got: BTreeSet<&str> = v
        .as_object()
        .unwrap_or_else(|| panic!("{what}: not an object: {v}"))
        .keys()
        .map(String::as_str)
        .collect();
    let want_set: BTreeSet<&str> = want.iter().copied().collect();
    assert_eq!(got, want_set, "{what}: keys (left: printed, right: documented)");
    let text = doc(page);
    for k in want {
        let named = text.match_indices(k).any(|(i, _)| {
            let before = text[..i].chars().next_back();
            let after = text[i + k.len()..].chars().next();
            let rest = text[i + k.len()..].trim_start_matches(' ');
            matches!(before, Some('{' | ' ' | '\n' | '"' | '`'))
                && (matches!(after, Some(',' | '}' | '"' | '`')) || rest.starts_with(['{', '[']))
        });
        assert!(named, "{what}: key {k} is not documented in docs/{page}");
    }
}
