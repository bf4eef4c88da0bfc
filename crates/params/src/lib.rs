//! What a method (builder, encoder, optimizer, layout) declares about itself, next to its
//! algorithm: name, paper reference, typed parameters with defaults and ranges ([`Method`]). The
//! pipeline registers each method with one line (`crates/pipeline/src/methods/`); `bvhlab
//! methods`, validation, experiment parsing and the report read that table.
//!
//! Values travel as canonical strings ([`Params`]): a parameter given as `3.0`, `3` or omitted
//! (default 3) has one spelling, so the cache key does not depend on how it was written. No
//! dependencies: every algorithm crate can describe its methods.
use std::collections::BTreeMap;
use std::str::FromStr;

/// Canonical parameters, `name -> value`, defaults filled in.
pub type Params = BTreeMap<String, String>;

/// Cross-parameter resolution after defaults are filled (e.g. AAC presets): gets the given
/// parameters and the canonical ones, may rewrite the latter; `Err` is the reason.
pub type FinishFn = fn(&Params, &mut Params) -> Result<(), String>;

/// A method's own display label from its canonical parameters (e.g. `aac HQ`).
pub type LabelFn = fn(&Params) -> String;

/// A parameter's type and range.
#[derive(Clone, Copy, Debug)]
pub enum Kind {
    /// Integer in `min..=max`.
    UInt { min: u32, max: u32 },
    /// Finite float > 0.
    PositiveFloat,
    /// Finite float >= 0.
    NonNegativeFloat,
    /// Finite float >= the bound.
    FloatAtLeast(f32),
    /// One of a fixed set of words.
    Choice(&'static [&'static str]),
    /// `auto` (resolved for the consuming method, e.g. `auto:aac`) or an integer in `min..=max`.
    AutoOrUInt { min: u32, max: u32 },
}

#[derive(Clone, Copy, Debug)]
pub struct ParamSpec {
    pub name: &'static str,
    pub default: &'static str,
    pub kind: Kind,
    pub about: &'static str,
    /// Shown in the method's label even at its default (e.g. `bins`); others only when changed.
    pub in_label: bool,
}

/// A method as it describes itself.
#[derive(Clone, Copy, Debug)]
pub struct Method {
    /// The name experiments and the command line use.
    pub name: &'static str,
    /// One line for `bvhlab methods`.
    pub about: &'static str,
    /// The paper (and section) the method follows; `about` cites it.
    pub reference: &'static str,
    pub params: &'static [ParamSpec],
    pub finish: Option<FinishFn>,
    pub label: Option<LabelFn>,
    /// Implementation version: bump it (`with_version`) when a change of this method changes what
    /// it produces. Part of its stage's key from 2 on (`method_version`), so only its nodes (and
    /// what is downstream of them) are recomputed.
    pub version: u32,
}

impl Method {
    /// A method without cross-parameter rules or own label.
    pub const fn new(
        name: &'static str,
        about: &'static str,
        reference: &'static str,
        params: &'static [ParamSpec],
    ) -> Method {
        Method {
            name,
            about,
            reference,
            params,
            finish: None,
            label: None,
            version: 1,
        }
    }
    pub const fn with_version(mut self, v: u32) -> Method {
        self.version = v;
        self
    }
    pub const fn with_finish(mut self, f: FinishFn) -> Method {
        self.finish = Some(f);
        self
    }
    pub const fn with_label(mut self, f: LabelFn) -> Method {
        self.label = Some(f);
        self
    }
}

/// Shortest round-trip form, so `3`, `3.0` and `3.00` share a key.
pub fn fmt_f32(v: f32) -> String {
    format!("{v}")
}

/// `value` checked against `spec` and in its canonical spelling; `Err` says what was expected.
/// `auto` names the consumer an `auto` value resolves for (`auto:<name>`).
pub fn canonical(spec: &ParamSpec, value: &str, auto: Option<&str>) -> Result<String, String> {
    let v = value.trim();
    let float = |ok: fn(f32) -> bool, want: String| match v.parse::<f32>() {
        // `+ 0.0` turns -0 into 0, so both spellings share a key.
        Ok(x) if x.is_finite() && ok(x) => Ok(fmt_f32(x + 0.0)),
        _ => Err(want),
    };
    match spec.kind {
        Kind::UInt { min, max } => match v.parse::<u64>() {
            Ok(n) if n >= min as u64 && n <= max as u64 => Ok(n.to_string()),
            _ => Err(format!("an integer in {min}..={max}")),
        },
        Kind::PositiveFloat => float(|x| x > 0.0, "a finite number > 0".into()),
        Kind::NonNegativeFloat => float(|x| x >= 0.0, "a finite number >= 0".into()),
        Kind::FloatAtLeast(min) => match v.parse::<f32>() {
            Ok(x) if x.is_finite() && x >= min => Ok(fmt_f32(x + 0.0)),
            _ => Err(format!("a finite number >= {}", fmt_f32(min))),
        },
        Kind::Choice(words) => match words.iter().find(|w| **w == v) {
            Some(w) => Ok(w.to_string()),
            None => Err(format!("one of {}", words.join(", "))),
        },
        Kind::AutoOrUInt { min, max } => {
            let want = || format!("`auto` or an integer in {min}..={max}");
            let resolved = auto.map(|a| format!("auto:{a}"));
            if v == "auto" || Some(v) == resolved.as_deref() {
                return resolved.ok_or_else(want);
            }
            match v.parse::<u64>() {
                Ok(n) if n >= min as u64 && n <= max as u64 => Ok(n.to_string()),
                _ => Err(want()),
            }
        }
    }
}

/// A parameter value that does not fit its spec.
#[derive(Clone, Debug, PartialEq)]
pub struct BadValue {
    pub param: &'static str,
    pub given: String,
    /// What was expected (`an integer in 2..=4096`).
    pub want: String,
}

/// How [`fill`] stores a valid value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Spelling {
    /// The canonical spelling ([`canonical`]).
    Canonical,
    /// As given, trimmed (layouts: their keys have held the values as written since layout
    /// version 1, so `mult_threshold=2.0` must stay `2.0`).
    AsGiven,
}

/// Every parameter of `specs` from `given` or its default, checked; `given` may hold names
/// `specs` does not have (see [`unknown`]).
pub fn fill(
    specs: &[ParamSpec],
    given: &Params,
    auto: Option<&str>,
    spelling: Spelling,
) -> Result<Params, BadValue> {
    let mut out = Params::new();
    for spec in specs {
        let value = given
            .get(spec.name)
            .map(String::as_str)
            .unwrap_or(spec.default);
        let canon = canonical(spec, value, auto).map_err(|want| BadValue {
            param: spec.name,
            given: value.to_string(),
            want,
        })?;
        let v = match spelling {
            Spelling::Canonical => canon,
            Spelling::AsGiven => value.trim().to_string(),
        };
        out.insert(spec.name.to_string(), v);
    }
    Ok(out)
}

/// The first name in `given` that none of `specs` has.
pub fn unknown<'a>(specs: &[&[ParamSpec]], given: &'a Params) -> Option<&'a str> {
    given
        .keys()
        .find(|k| !specs.iter().any(|s| s.iter().any(|p| p.name == k.as_str())))
        .map(String::as_str)
}

/// `a, b, c`, or `(none)`.
pub fn names(specs: &[ParamSpec]) -> String {
    if specs.is_empty() {
        return "(none)".into();
    }
    specs.iter().map(|p| p.name).collect::<Vec<_>>().join(", ")
}

/// Typed reads of canonical parameters.
pub trait Read {
    /// `name` parsed as `T`; `T::default()` when absent or unparsable (after [`fill`] every
    /// parameter of the schema is present and valid, so that happens only for other names).
    fn typed<T: FromStr + Default>(&self, name: &str) -> T;
    /// `name`'s value, `""` when absent.
    fn word(&self, name: &str) -> &str;
}

impl Read for Params {
    fn typed<T: FromStr + Default>(&self, name: &str) -> T {
        self.get(name)
            .and_then(|v| v.parse().ok())
            .unwrap_or_default()
    }
    fn word(&self, name: &str) -> &str {
        self.get(name).map(String::as_str).unwrap_or("")
    }
}

/// `FromStr` for an enum whose variants are the values of a [`Kind::Choice`] parameter, from its
/// table of names: `choice_from_str!(Axes { "largest" => Axes::Largest, "all" => Axes::All });`.
#[macro_export]
macro_rules! choice_from_str {
    ($t:ty { $($name:literal => $v:expr),+ $(,)? }) => {
        impl std::str::FromStr for $t {
            type Err = ();
            fn from_str(s: &str) -> Result<$t, ()> {
                match s {
                    $($name => Ok($v),)+
                    _ => Err(()),
                }
            }
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    const BINS: ParamSpec = ParamSpec {
        name: "bins",
        default: "16",
        kind: Kind::UInt { min: 2, max: 4096 },
        about: "",
        in_label: true,
    };
    const T: ParamSpec = ParamSpec {
        name: "t",
        default: "2.0",
        kind: Kind::FloatAtLeast(1.0),
        about: "",
        in_label: false,
    };

    fn given(kv: &[(&str, &str)]) -> Params {
        kv.iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }

    #[test]
    fn canonical_spellings() {
        let f = ParamSpec {
            kind: Kind::NonNegativeFloat,
            ..T
        };
        assert_eq!(canonical(&f, " -0.0 ", None).unwrap(), "0");
        assert_eq!(canonical(&f, "3.00", None).unwrap(), "3");
        assert_eq!(canonical(&BINS, "016", None).unwrap(), "16");
        assert!(canonical(&BINS, "1", None)
            .unwrap_err()
            .contains("2..=4096"));
        assert!(canonical(&T, "0.5", None).unwrap_err().contains(">= 1"));
        let bits = ParamSpec {
            kind: Kind::AutoOrUInt { min: 1, max: 21 },
            ..BINS
        };
        assert_eq!(canonical(&bits, "auto", Some("aac")).unwrap(), "auto:aac");
        assert_eq!(
            canonical(&bits, "auto:aac", Some("aac")).unwrap(),
            "auto:aac"
        );
        assert!(canonical(&bits, "auto:ploc", Some("aac")).is_err());
        assert!(canonical(&bits, "auto", None).is_err());
    }

    #[test]
    fn fill_keeps_or_normalizes_spellings() {
        let specs = [BINS, T];
        let g = given(&[("t", " 2.50 "), ("other", "x")]);
        let c = fill(&specs, &g, None, Spelling::Canonical).unwrap();
        assert_eq!((c["bins"].as_str(), c["t"].as_str()), ("16", "2.5"));
        let a = fill(&specs, &g, None, Spelling::AsGiven).unwrap();
        assert_eq!((a["bins"].as_str(), a["t"].as_str()), ("16", "2.50"));
        assert_eq!(unknown(&[&specs], &g), Some("other"));
        let e = fill(&specs, &given(&[("bins", "x")]), None, Spelling::AsGiven).unwrap_err();
        assert_eq!((e.param, e.given.as_str()), ("bins", "x"));
        assert_eq!(c.typed::<u32>("bins"), 16);
        assert_eq!(c.typed::<u32>("nope"), 0);
    }
}
