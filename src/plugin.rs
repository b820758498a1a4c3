//! What the material and shape registries share: a list of plug-ins by the tag a scene names
//! them with, each with the function that reads its parameters through `erased_serde` (which
//! keeps serde's message), and the serde pieces that read `Tag((parameters...))`.

use serde::de::{self, DeserializeSeed, Deserializer, Visitor};
use std::fmt;
use std::sync::RwLock;

/// Reads a plug-in's parameters into `T`.
pub type Parse<T> =
    for<'a, 'de> fn(&'a mut dyn erased_serde::Deserializer<'de>) -> Result<T, erased_serde::Error>;

/// Plug-ins registered at run time, by tag.
pub struct Registry<T: 'static>(RwLock<Vec<(&'static str, Parse<T>)>>);

impl<T: 'static> Registry<T> {
    pub const fn new() -> Self {
        Registry(RwLock::new(Vec::new()))
    }

    /// Adds `tag`, replacing an earlier registration of it.
    pub fn insert(&self, tag: &'static str, parse: Parse<T>) {
        let mut r = self.0.write().unwrap_or_else(|e| e.into_inner());
        r.retain(|(t, _)| *t != tag);
        r.push((tag, parse));
    }

    pub fn get(&self, tag: &str) -> Option<Parse<T>> {
        let r = self.0.read().unwrap_or_else(|e| e.into_inner());
        r.iter().find(|(t, _)| *t == tag).map(|(_, p)| *p)
    }

    /// `first`, then every registered tag, for the message of an unknown one. Only on that
    /// error path does it allocate, and it leaks the list to give serde a `'static` slice.
    pub fn known(&self, first: &'static [&'static str]) -> &'static [&'static str] {
        let r = self.0.read().unwrap_or_else(|e| e.into_inner());
        if r.is_empty() {
            return first;
        }
        let all: Vec<&'static str> = first
            .iter()
            .copied()
            .chain(r.iter().map(|(t, _)| *t))
            .collect();
        Box::leak(all.into_boxed_slice())
    }
}

impl<T: 'static> Default for Registry<T> {
    fn default() -> Self {
        Self::new()
    }
}

/// A variant's name, read as an identifier (what RON writes before the parentheses).
pub struct Tag;

impl<'de> DeserializeSeed<'de> for Tag {
    type Value = String;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<String, D::Error> {
        d.deserialize_identifier(TagVisitor)
    }
}

struct TagVisitor;

impl<'de> Visitor<'de> for TagVisitor {
    type Value = String;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a plug-in's name")
    }
    fn visit_str<E: de::Error>(self, v: &str) -> Result<String, E> {
        Ok(v.to_string())
    }
}

/// Reads a registered plug-in's parameters with its [`Parse`].
pub struct Seed<T: 'static>(pub Parse<T>);

impl<'de, T: 'static> DeserializeSeed<'de> for Seed<T> {
    type Value = T;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<T, D::Error> {
        let mut erased = <dyn erased_serde::Deserializer>::erase(d);
        (self.0)(&mut erased).map_err(de::Error::custom)
    }
}
