//! Solver knobs: each solver's table ([`Knob`]: name, default, range, meaning) is the one place
//! a knob is written. `--set solver.key=value` is checked against it before any device work
//! (unknown knob, knob of another solver, value out of range), the knob reference
//! (`scatterlab knobs`, `docs/knobs.md`) is printed from it, and `scene info` estimates memory
//! from its defaults. A solver reads its values through [`Knobs`], which also records what
//! each render ran with (the `settings` of the report) and refuses a knob that was set but
//! not used by the render (a typo or a knob of a mode not chosen never passes silently).

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

use serde::Serialize;

use super::SolverError;

/// The values a knob accepts.
#[derive(Clone, Debug, PartialEq)]
pub enum Range {
    /// A whole number in `min..=max`.
    Int { min: u64, max: u64 },
    /// A whole number in `min..=max`, or the word (`unbounded`).
    IntOr { min: u64, max: u64, word: &'static str },
    /// A finite real number between `min` and `max`, each end open or closed.
    Real { min: f64, max: f64, min_open: bool, max_open: bool },
    /// One of these words.
    Choice(&'static [&'static str]),
    /// `true` or `false`.
    Bool,
    /// One of these words, or the prefix followed by a non-empty argument (`file:DIR`).
    ChoiceOrPrefix(&'static [&'static str], &'static str),
}

impl Range {
    pub const fn int(min: u64, max: u64) -> Range {
        Range::Int { min, max }
    }
    /// A length or rate: finite and > 0.
    pub const fn positive() -> Range {
        Range::Real { min: 0.0, max: f64::INFINITY, min_open: true, max_open: true }
    }
    /// A fraction strictly between 0 and 1 (a tolerance, a threshold).
    pub const fn open_unit() -> Range {
        Range::Real { min: 0.0, max: 1.0, min_open: true, max_open: true }
    }
    pub const fn non_negative() -> Range {
        Range::Real { min: 0.0, max: f64::INFINITY, min_open: false, max_open: true }
    }

    /// `Ok` when `text` is a value of this range, else why not.
    pub fn check(&self, text: &str) -> Result<(), String> {
        let t = text.trim();
        match *self {
            Range::Int { min, max } => match t.parse::<u64>() {
                Ok(v) if (min..=max).contains(&v) => Ok(()),
                _ => Err(format!("{t:?} is not {self}")),
            },
            Range::IntOr { min, max, word } => match t.parse::<u64>() {
                Ok(v) if (min..=max).contains(&v) => Ok(()),
                _ if t == word => Ok(()),
                _ => Err(format!("{t:?} is not {self}")),
            },
            Range::Real { min, max, min_open, max_open } => match t.parse::<f64>() {
                Ok(v)
                    if v.is_finite()
                        && (v > min || (!min_open && v == min))
                        && (v < max || (!max_open && v == max)) =>
                {
                    Ok(())
                }
                _ => Err(format!("{t:?} is not {self}")),
            },
            Range::Choice(words) => {
                if words.contains(&t) {
                    Ok(())
                } else {
                    Err(format!("{t:?} is not {self}"))
                }
            }
            Range::Bool => match t {
                "true" | "false" => Ok(()),
                _ => Err(format!("{t:?} is not {self}")),
            },
            Range::ChoiceOrPrefix(words, prefix) => {
                if words.contains(&t) || t.strip_prefix(prefix).is_some_and(|rest| !rest.is_empty()) {
                    Ok(())
                } else {
                    Err(format!("{t:?} is not {self}"))
                }
            }
        }
    }
}

impl fmt::Display for Range {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        match *self {
            Range::Int { min, max } => write!(f, "an integer in {min}..={max}"),
            Range::IntOr { min, max, word } => write!(f, "an integer in {min}..={max} or `{word}`"),
            Range::Real { min, max, min_open, max_open } => {
                let lo = if min_open { "(" } else { "[" };
                let hi = if max_open { ")" } else { "]" };
                write!(f, "a number in {lo}{min}, {max}{hi}")
            }
            Range::Choice(words) => write!(f, "one of {}", words.join(", ")),
            Range::Bool => write!(f, "true or false"),
            Range::ChoiceOrPrefix(words, prefix) => write!(f, "one of {} or {prefix}PATH", words.join(", ")),
        }
    }
}

/// Where a knob's value comes from when it is not set.
#[derive(Clone, Debug, PartialEq)]
pub enum Default {
    /// This value, written as on the command line.
    Fixed(&'static str),
    /// Computed by the solver from the scene or other knobs; the text says how.
    Derived(&'static str),
}

/// One knob of a solver (`--set <solver>.<name>=<value>`).
#[derive(Clone, Debug, PartialEq)]
pub struct Knob {
    /// Without the solver's prefix: `grid`, `view_step`.
    pub name: String,
    pub default: Default,
    pub range: Range,
    /// What it does, with units; one sentence or two.
    pub doc: &'static str,
    /// The setting it applies under, when not always (`warm_start=wavefront`): a render that
    /// does not use it refuses it, naming this.
    pub only_with: Option<&'static str>,
}

impl Knob {
    pub fn fixed(name: impl Into<String>, default: &'static str, range: Range, doc: &'static str) -> Knob {
        Knob { name: name.into(), default: Default::Fixed(default), range, doc, only_with: None }
    }
    pub fn derived(name: impl Into<String>, how: &'static str, range: Range, doc: &'static str) -> Knob {
        Knob { name: name.into(), default: Default::Derived(how), range, doc, only_with: None }
    }
    /// The same knob under `prefix` (a shared part's knobs inside a solver: `view_step`).
    pub fn prefixed(mut self, prefix: &str) -> Knob {
        self.name = format!("{prefix}{}", self.name);
        self
    }
    /// The same knob, applying only under `setting` (a knob of a mode: `warm_start=wavefront`).
    pub fn only_with(mut self, setting: &'static str) -> Knob {
        self.only_with = Some(setting);
        self
    }

    /// The default as text: the value, or how it is derived.
    pub fn default_text(&self) -> String {
        match &self.default {
            Default::Fixed(v) => v.to_string(),
            Default::Derived(how) => how.to_string(),
        }
    }
}

/// `--set` pairs of solver knobs, as given (`("lbl.grid", "32")`); scene keys are applied to
/// the scene itself, not kept here.
#[derive(Clone, Debug, Default)]
pub struct Settings {
    pairs: BTreeMap<String, String>,
}

impl Settings {
    pub fn new(pairs: &[(String, String)]) -> Settings {
        Settings { pairs: pairs.iter().map(|(k, v)| (k.trim().to_string(), v.trim().to_string())).collect() }
    }

    /// Only the pairs of `solver` (a memory estimate per solver from one command line).
    pub fn only(&self, solver: &str) -> Settings {
        let prefix = format!("{solver}.");
        Settings {
            pairs: self
                .pairs
                .iter()
                .filter(|(k, _)| k.starts_with(&prefix))
                .map(|(k, v)| (k.clone(), v.clone()))
                .collect(),
        }
    }

    /// These settings with `key` set to `value` (replacing any value it had).
    pub fn with(&self, key: &str, value: &str) -> Settings {
        let mut out = self.clone();
        out.pairs.insert(key.to_string(), value.to_string());
        out
    }

    pub fn pairs(&self) -> impl Iterator<Item = (&str, &str)> {
        self.pairs.iter().map(|(k, v)| (k.as_str(), v.as_str()))
    }

    /// The values of `solver`'s knobs: every pair must name one of its knobs (not another
    /// solver's, not an unknown one) with a value in the knob's range.
    pub fn knobs(&self, solver: &str, table: Vec<Knob>) -> Result<Knobs, SolverError> {
        let mut given = BTreeMap::new();
        for (key, value) in &self.pairs {
            let (owner, name) = key.split_once('.').unwrap_or(("", key));
            if owner != solver {
                let reason = if super::registered().iter().any(|s| s.name() == owner) {
                    format!("is a knob of solver {owner}, but this render uses solver {solver}")
                } else {
                    format!(
                        "unknown key; solver knobs start with a solver name ({})",
                        super::registered().iter().map(|s| s.name()).collect::<Vec<_>>().join(", ")
                    )
                };
                return Err(SolverError::Setting { key: key.clone(), reason });
            }
            let Some(knob) = table.iter().find(|k| k.name == name) else {
                let known: Vec<&str> = table.iter().map(|k| k.name.as_str()).collect();
                let hint = if ["spp", "seed", "width", "height"].contains(&name) {
                    format!(" (it is a scene key: render.{name}, as --set render.{name}=...)")
                } else if let Some(close) = crate::scene::did_you_mean(name, &known) {
                    format!(" (did you mean {solver}.{close}?)")
                } else {
                    String::new()
                };
                return Err(SolverError::Setting {
                    key: key.clone(),
                    reason: format!("unknown knob of solver {solver}{hint}; known: {}", known.join(", ")),
                });
            };
            knob.range.check(value).map_err(|reason| SolverError::Setting {
                key: key.clone(),
                reason: format!("{reason} (`scatterlab knobs {solver}` lists every knob)"),
            })?;
            given.insert(name.to_string(), value.clone());
        }
        Ok(Knobs { solver: solver.to_string(), table, given, used: RefCell::default() })
    }
}

/// The knob values of one render of one solver, typed on reading.
#[derive(Debug)]
pub struct Knobs {
    solver: String,
    table: Vec<Knob>,
    /// Set by the user, by name without prefix; checked against the table.
    given: BTreeMap<String, String>,
    /// What the render read, with the value it ran with (for the report's `settings`).
    used: RefCell<BTreeMap<String, serde_json::Value>>,
}

impl Knobs {
    /// Every knob at its default (for estimates and tests).
    pub fn defaults(solver: &str, table: Vec<Knob>) -> Knobs {
        Knobs { solver: solver.to_string(), table, given: BTreeMap::new(), used: RefCell::default() }
    }

    fn knob(&self, name: &str) -> Result<&Knob, SolverError> {
        self.table.iter().find(|k| k.name == name).ok_or_else(|| SolverError::Setting {
            key: format!("{}.{name}", self.solver),
            reason: "read by the solver but missing from its knob table (a bug: please report it)".into(),
        })
    }

    fn parse<T: FromStr>(&self, name: &str, text: &str) -> Result<T, SolverError>
    where
        T::Err: fmt::Display,
    {
        text.trim().parse::<T>().map_err(|e| SolverError::Setting {
            key: format!("{}.{name}", self.solver),
            reason: format!("cannot parse {text:?}: {e}"),
        })
    }

    fn record<T: Serialize>(&self, name: &str, value: &T) {
        self.used.borrow_mut().insert(name.to_string(), serde_json::to_value(value).unwrap_or_default());
    }

    /// The error for knob `name` (without prefix) holding a value the render cannot use.
    pub fn invalid(&self, name: &str, reason: impl Into<String>) -> SolverError {
        SolverError::Setting { key: format!("{}.{name}", self.solver), reason: reason.into() }
    }

    /// Whether the user set this knob.
    pub fn is_set(&self, name: &str) -> bool {
        self.given.contains_key(name)
    }

    /// A knob with a fixed default.
    pub fn get<T: FromStr + Serialize>(&self, name: &str) -> Result<T, SolverError>
    where
        T::Err: fmt::Display,
    {
        let knob = self.knob(name)?;
        let text = match (self.given.get(name), &knob.default) {
            (Some(v), _) => v.clone(),
            (None, Default::Fixed(d)) => d.to_string(),
            (None, Default::Derived(_)) => {
                return Err(SolverError::Setting {
                    key: format!("{}.{name}", self.solver),
                    reason: "has a derived default but was read without one (a bug: please report it)".into(),
                })
            }
        };
        let v = self.parse(name, &text)?;
        self.record(name, &v);
        Ok(v)
    }

    /// A knob with a derived default: `derived` unless set. The derived value is held to the
    /// knob's range too.
    pub fn get_or<T: FromStr + Serialize + ToString>(&self, name: &str, derived: T) -> Result<T, SolverError>
    where
        T::Err: fmt::Display,
    {
        let knob = self.knob(name)?;
        let v = match self.given.get(name) {
            Some(text) => self.parse(name, text)?,
            None => {
                knob.range.check(&derived.to_string()).map_err(|reason| SolverError::Setting {
                    key: format!("{}.{name}", self.solver),
                    reason: format!("its default for this scene ({}) gives {reason}; set it", knob.default_text()),
                })?;
                derived
            }
        };
        self.record(name, &v);
        Ok(v)
    }

    /// Error on a knob that was set but not read by this render (it would have been ignored:
    /// a knob of a mode the render did not use).
    pub fn finish(&self) -> Result<(), SolverError> {
        let used = self.used.borrow();
        match self.given.keys().find(|k| !used.contains_key(*k)) {
            None => Ok(()),
            Some(k) => {
                let when = match self.table.iter().find(|t| &t.name == k).and_then(|t| t.only_with) {
                    Some(w) => format!("; it applies only with {}.{w}", self.solver),
                    None => String::new(),
                };
                Err(SolverError::Setting {
                    key: format!("{}.{k}", self.solver),
                    reason: format!("was set but this render does not use it{when}"),
                })
            }
        }
    }

    /// What the render read, by knob name, with the values it ran with.
    pub fn json(&self) -> serde_json::Value {
        serde_json::Value::Object(self.used.borrow().iter().map(|(k, v)| (k.clone(), v.clone())).collect())
    }
}

/// The knob reference of `solvers` as Markdown: `docs/knobs.md` is this for every registered
/// solver (a test keeps it so), `scatterlab knobs --markdown` prints it.
pub fn reference_markdown(solvers: &[&dyn super::Solver]) -> String {
    let mut s = String::from(
        "# Solver knobs\n\nGenerated by `scatterlab knobs --markdown` from each solver's knob table (the one place a \
         knob is written); do not edit by hand. Set a knob with `--set <solver>.<knob>=<value>`. Samples per pixel \
         are the scene's `render.spp` (`--spp N`), for `path` only.\n",
    );
    for solver in solvers {
        s.push_str(&format!("\n## `{}`\n\n{}\n\n", solver.name(), solver.about()));
        s.push_str("| knob | default | values | meaning |\n| --- | --- | --- | --- |\n");
        for k in solver.knobs() {
            let default = match &k.default {
                Default::Fixed(v) => format!("`{v}`"),
                Default::Derived(how) => how.to_string(),
            };
            let doc = match k.only_with {
                Some(w) => format!("{} (only with `{}.{w}`)", k.doc, solver.name()),
                None => k.doc.to_string(),
            };
            s.push_str(&format!(
                "| `{}.{}` | {} | {} | {} |\n",
                solver.name(),
                k.name,
                default,
                k.range.to_string().replace('|', "\\|"),
                doc.replace('|', "\\|")
            ));
        }
    }
    s
}

/// One solver's knobs as text for the terminal.
pub fn reference_text(solver: &dyn super::Solver) -> String {
    let mut s = format!("{}: {}\n", solver.name(), solver.about());
    let knobs = solver.knobs();
    let width = knobs.iter().map(|k| k.name.len()).max().unwrap_or(0) + solver.name().len() + 1;
    for k in knobs {
        s.push_str(&format!(
            "  {:<width$}  default {}; {}\n  {:<width$}  {}{}\n",
            format!("{}.{}", solver.name(), k.name),
            k.default_text(),
            k.range,
            "",
            k.doc,
            k.only_with.map(|w| format!(" (only with {}.{w})", solver.name())).unwrap_or_default()
        ));
    }
    s
}
