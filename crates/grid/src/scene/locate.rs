//! Where in a scene file an error lies: file, line, column and the dotted
//! field path (`object[2].shape.radius`), for serde's errors and the
//! checks' alike.

use crate::error::{Error, Location, Result};

/// `text` read as `T` through serde, a failure located by line, column
/// and field.
pub(crate) fn deserialize<T: serde::de::DeserializeOwned>(text: &str, origin: &str) -> Result<T> {
    let de = toml::Deserializer::new(text);
    serde_path_to_error::deserialize(de).map_err(|e| {
        let field = e.path().to_string();
        let inner = e.into_inner();
        Error::Invalid {
            at: Location {
                file: origin.to_string(),
                line_column: inner.span().map(|s| line_column(text, s.start)),
                field: if field == "." { String::new() } else { field },
            },
            message: inner.message().trim().replace('\n', ": "),
        }
    })
}

/// One step of a field path.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Seg<'a> {
    Key(&'a str),
    Index(usize),
}

fn path_string(path: &[Seg]) -> String {
    let mut s = String::new();
    for seg in path {
        match seg {
            Seg::Key(k) => {
                if !s.is_empty() {
                    s.push('.');
                }
                s.push_str(k);
            }
            Seg::Index(i) => s.push_str(&format!("[{i}]")),
        }
    }
    s
}

fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, col)
}

/// Byte offset of the deepest part of `path` that exists in the document.
fn locate(text: &str, path: &[Seg]) -> Option<usize> {
    let doc = toml_edit::ImDocument::parse(text).ok()?;
    let mut item = doc.as_item();
    let mut best = None;
    for seg in path {
        let next = match seg {
            Seg::Key(k) => {
                // Prefer the key's own position: that is where a reader looks.
                let key_span = match item {
                    toml_edit::Item::Table(t) => t.key(k).and_then(|k| k.span()),
                    toml_edit::Item::Value(toml_edit::Value::InlineTable(t)) => {
                        t.key(k).and_then(|k| k.span())
                    }
                    _ => None,
                };
                let next = item.get(*k);
                if let Some(s) = key_span.or_else(|| next.and_then(|n| n.span())) {
                    best = Some(s.start);
                }
                next
            }
            Seg::Index(i) => {
                let next = item.get(*i);
                if let Some(s) = next.and_then(|n| n.span()) {
                    best = Some(s.start);
                }
                next
            }
        };
        match next {
            Some(n) => item = n,
            None => break,
        }
    }
    best
}

/// Builds located errors while a scene is checked.
pub(crate) struct Checker<'a> {
    pub(crate) origin: &'a str,
    pub(crate) text: &'a str,
}

impl Checker<'_> {
    pub(crate) fn err(&self, path: &[Seg], message: impl Into<String>) -> Error {
        Error::Invalid {
            at: Location {
                file: self.origin.to_string(),
                line_column: locate(self.text, path).map(|o| line_column(self.text, o)),
                field: path_string(path),
            },
            message: message.into(),
        }
    }
}

/// The segments of a dotted field path (`object[2].shape.radius`).
pub(super) fn parse_path(field: &str) -> Vec<Seg<'_>> {
    let mut out = Vec::new();
    for part in field.split('.') {
        let (key, rest) = part.split_once('[').unwrap_or((part, ""));
        if !key.is_empty() {
            out.push(Seg::Key(key));
        }
        for idx in rest.split('[') {
            if let Ok(i) = idx.trim_end_matches(']').parse() {
                out.push(Seg::Index(i));
            }
        }
    }
    out
}
