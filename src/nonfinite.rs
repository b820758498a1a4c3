//! Finds the first non-finite floating-point field of any serializable value, by its path.
//!
//! Scene validation checks each field's range where it knows one; this walk is the catch-all
//! behind those checks, so that a NaN or an infinity in a field without its own check (a
//! rotation, a loss target, a recording option, or a field added later) is refused with its
//! name instead of reaching the simulation, where it would give a silent NaN or an empty body.
//!
//! Paths follow the scene's own spelling: struct fields and map keys joined by `.`, list and
//! tuple items as `[i]`, while `Some(..)`, enum variants and newtype wrappers add nothing
//! (`colliders[2].rotation_deg[1]`, `task.target_value`, `loss.grams`).

use serde::ser::{self, Serialize};
use std::fmt;

/// The path and value of the first non-finite `f32`/`f64` in `value`, in serialization order.
pub fn first_nonfinite<T: Serialize + ?Sized>(value: &T) -> Option<(String, f64)> {
    let mut w = Walker {
        path: Vec::new(),
        found: None,
    };
    // The walker's only error is `Found`, which stops the walk early.
    let _ = value.serialize(&mut w);
    w.found
}

struct Walker {
    path: Vec<String>,
    found: Option<(String, f64)>,
}

impl Walker {
    fn path_string(&self) -> String {
        let mut s = String::new();
        for p in &self.path {
            if !p.starts_with('[') && !s.is_empty() {
                s.push('.');
            }
            s.push_str(p);
        }
        s
    }

    fn float(&mut self, v: f64) -> Result<(), Found> {
        if v.is_finite() {
            Ok(())
        } else {
            self.found = Some((self.path_string(), v));
            Err(Found)
        }
    }

    fn nested<T: Serialize + ?Sized>(&mut self, seg: String, v: &T) -> Result<(), Found> {
        self.path.push(seg);
        let r = v.serialize(&mut *self);
        self.path.pop();
        r
    }
}

/// Stops the walk at the first non-finite value.
#[derive(Debug)]
struct Found;

impl fmt::Display for Found {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("non-finite value found")
    }
}

impl std::error::Error for Found {}

impl ser::Error for Found {
    fn custom<T: fmt::Display>(_: T) -> Self {
        Found
    }
}

/// Compound values: counts their items for the `[i]` segments.
struct Compound<'a> {
    w: &'a mut Walker,
    index: usize,
}

impl Compound<'_> {
    fn item<T: Serialize + ?Sized>(&mut self, v: &T) -> Result<(), Found> {
        let seg = format!("[{}]", self.index);
        self.index += 1;
        self.w.nested(seg, v)
    }
}

/// Serializer methods that accept a value and look no further.
macro_rules! ignore {
    ($($method:ident : $ty:ty),*) => {$(
        fn $method(self, _: $ty) -> Result<(), Found> {
            Ok(())
        }
    )*};
}

impl<'a> ser::Serializer for &'a mut Walker {
    type Ok = ();
    type Error = Found;
    type SerializeSeq = Compound<'a>;
    type SerializeTuple = Compound<'a>;
    type SerializeTupleStruct = Compound<'a>;
    type SerializeTupleVariant = Compound<'a>;
    type SerializeMap = MapWalker<'a>;
    type SerializeStruct = Compound<'a>;
    type SerializeStructVariant = Compound<'a>;

    // Everything but a float is finite by construction.
    ignore!(
        serialize_bool: bool,
        serialize_i8: i8,
        serialize_i16: i16,
        serialize_i32: i32,
        serialize_i64: i64,
        serialize_u8: u8,
        serialize_u16: u16,
        serialize_u32: u32,
        serialize_u64: u64,
        serialize_char: char,
        serialize_str: &str,
        serialize_bytes: &[u8]
    );
    fn serialize_f32(self, v: f32) -> Result<(), Found> {
        self.float(v as f64)
    }
    fn serialize_f64(self, v: f64) -> Result<(), Found> {
        self.float(v)
    }
    fn serialize_none(self) -> Result<(), Found> {
        Ok(())
    }
    fn serialize_some<T: Serialize + ?Sized>(self, v: &T) -> Result<(), Found> {
        v.serialize(self)
    }
    fn serialize_unit(self) -> Result<(), Found> {
        Ok(())
    }
    fn serialize_unit_struct(self, _: &'static str) -> Result<(), Found> {
        Ok(())
    }
    fn serialize_unit_variant(self, _: &'static str, _: u32, _: &'static str) -> Result<(), Found> {
        Ok(())
    }
    fn serialize_newtype_struct<T: Serialize + ?Sized>(
        self,
        _: &'static str,
        v: &T,
    ) -> Result<(), Found> {
        v.serialize(self)
    }
    fn serialize_newtype_variant<T: Serialize + ?Sized>(
        self,
        _: &'static str,
        _: u32,
        _: &'static str,
        v: &T,
    ) -> Result<(), Found> {
        v.serialize(self)
    }
    fn serialize_seq(self, _: Option<usize>) -> Result<Compound<'a>, Found> {
        Ok(Compound { w: self, index: 0 })
    }
    fn serialize_tuple(self, _: usize) -> Result<Compound<'a>, Found> {
        Ok(Compound { w: self, index: 0 })
    }
    fn serialize_tuple_struct(self, _: &'static str, _: usize) -> Result<Compound<'a>, Found> {
        Ok(Compound { w: self, index: 0 })
    }
    fn serialize_tuple_variant(
        self,
        _: &'static str,
        _: u32,
        _: &'static str,
        _: usize,
    ) -> Result<Compound<'a>, Found> {
        Ok(Compound { w: self, index: 0 })
    }
    fn serialize_map(self, _: Option<usize>) -> Result<MapWalker<'a>, Found> {
        Ok(MapWalker {
            w: self,
            key: String::new(),
        })
    }
    fn serialize_struct(self, _: &'static str, _: usize) -> Result<Compound<'a>, Found> {
        Ok(Compound { w: self, index: 0 })
    }
    fn serialize_struct_variant(
        self,
        _: &'static str,
        _: u32,
        _: &'static str,
        _: usize,
    ) -> Result<Compound<'a>, Found> {
        Ok(Compound { w: self, index: 0 })
    }
}

/// Lists and tuples of every kind: each item is the next `[i]`.
macro_rules! items {
    ($($trait:ident :: $method:ident),*) => {$(
        impl ser::$trait for Compound<'_> {
            type Ok = ();
            type Error = Found;
            fn $method<T: Serialize + ?Sized>(&mut self, v: &T) -> Result<(), Found> {
                self.item(v)
            }
            fn end(self) -> Result<(), Found> {
                Ok(())
            }
        }
    )*};
}
items!(
    SerializeSeq::serialize_element,
    SerializeTuple::serialize_element,
    SerializeTupleStruct::serialize_field,
    SerializeTupleVariant::serialize_field
);

/// Structs and struct variants: each field is a `.name` segment.
macro_rules! fields {
    ($($trait:ident),*) => {$(
        impl ser::$trait for Compound<'_> {
            type Ok = ();
            type Error = Found;
            fn serialize_field<T: Serialize + ?Sized>(
                &mut self,
                name: &'static str,
                v: &T,
            ) -> Result<(), Found> {
                self.w.nested(name.to_string(), v)
            }
            fn end(self) -> Result<(), Found> {
                Ok(())
            }
        }
    )*};
}
fields!(SerializeStruct, SerializeStructVariant);

/// Maps: a string key names its value's path segment.
struct MapWalker<'a> {
    w: &'a mut Walker,
    key: String,
}

impl ser::SerializeMap for MapWalker<'_> {
    type Ok = ();
    type Error = Found;
    fn serialize_key<T: Serialize + ?Sized>(&mut self, k: &T) -> Result<(), Found> {
        self.key = key_name(k);
        Ok(())
    }
    fn serialize_value<T: Serialize + ?Sized>(&mut self, v: &T) -> Result<(), Found> {
        let seg = std::mem::take(&mut self.key);
        self.w.nested(seg, v)
    }
    fn end(self) -> Result<(), Found> {
        Ok(())
    }
}

/// A map key as text: a string as itself, anything else as `?`.
fn key_name<T: Serialize + ?Sized>(k: &T) -> String {
    match serde_json::to_value(k) {
        Ok(serde_json::Value::String(s)) => s,
        _ => "?".to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Serialize;
    use std::collections::BTreeMap;

    #[derive(Serialize)]
    struct Inner {
        a: f64,
        b: (f64, f64, f64),
        c: Option<f32>,
    }

    #[derive(Serialize)]
    enum Amount {
        Grams(f64),
        Both { lo: f64, hi: f64 },
    }

    #[derive(Serialize)]
    struct Outer {
        n: usize,
        list: Vec<Inner>,
        map: BTreeMap<String, Amount>,
    }

    fn outer() -> Outer {
        let inner = |a| Inner {
            a,
            b: (1.0, 2.0, 3.0),
            c: Some(1.0),
        };
        Outer {
            n: 3,
            list: vec![inner(0.0), inner(1.0)],
            map: [
                ("x".to_string(), Amount::Grams(1.0)),
                ("y".to_string(), Amount::Both { lo: 0.0, hi: 1.0 }),
            ]
            .into_iter()
            .collect(),
        }
    }

    #[test]
    fn finite_values_pass() {
        assert_eq!(first_nonfinite(&outer()), None);
    }

    #[test]
    fn paths_name_fields_items_and_map_keys() {
        let mut o = outer();
        o.list[1].b.1 = f64::NAN;
        let (p, v) = first_nonfinite(&o).unwrap();
        assert_eq!(p, "list[1].b[1]");
        assert!(v.is_nan());

        let mut o = outer();
        o.list[0].c = Some(f32::INFINITY);
        assert_eq!(
            first_nonfinite(&o),
            Some(("list[0].c".to_string(), f64::INFINITY))
        );

        let mut o = outer();
        o.map.insert("x".into(), Amount::Grams(f64::NEG_INFINITY));
        assert_eq!(
            first_nonfinite(&o),
            Some(("map.x".to_string(), f64::NEG_INFINITY))
        );

        let mut o = outer();
        o.map.insert(
            "y".into(),
            Amount::Both {
                lo: 0.0,
                hi: f64::NAN,
            },
        );
        assert_eq!(first_nonfinite(&o).unwrap().0, "map.y.hi");
    }

    #[test]
    fn the_first_in_order_is_reported() {
        let mut o = outer();
        o.list[0].a = f64::NAN;
        o.list[1].a = f64::INFINITY;
        assert_eq!(first_nonfinite(&o).unwrap().0, "list[0].a");
    }
}
