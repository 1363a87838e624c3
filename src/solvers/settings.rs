//! Solver knobs from `--set solver.key=value`: parsed once, each read by the solver that owns
//! it, and any left unread at the end is an error naming it (a typo never passes silently).

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::str::FromStr;

use super::SolverError;

#[derive(Debug, Default)]
pub struct Settings {
    values: BTreeMap<String, String>,
    used: RefCell<Vec<String>>,
}

impl Settings {
    pub fn new(pairs: &[(String, String)]) -> Settings {
        Settings { values: pairs.iter().cloned().collect(), used: RefCell::default() }
    }

    /// `solver.key` parsed as T, or `default` when not given.
    pub fn get<T: FromStr>(&self, solver: &str, key: &str, default: T) -> Result<T, SolverError>
    where
        T::Err: std::fmt::Display,
    {
        let full = format!("{solver}.{key}");
        self.used.borrow_mut().push(full.clone());
        match self.values.get(&full) {
            None => Ok(default),
            Some(v) => v
                .trim()
                .parse::<T>()
                .map_err(|e| SolverError::Setting { key: full, reason: format!("cannot parse {v:?}: {e}") }),
        }
    }

    /// Error on any `solver.*` key the solver did not read.
    pub fn check_all_used(&self, solver: &str) -> Result<(), SolverError> {
        let used = self.used.borrow();
        for k in self.values.keys() {
            if !k.starts_with(&format!("{solver}.")) {
                let other = k.split('.').next().unwrap_or(k);
                return Err(SolverError::Setting {
                    key: k.clone(),
                    reason: format!("is a setting of solver {other}, but this render uses solver {solver}"),
                });
            }
            if !used.contains(k) {
                let known: Vec<&String> = used.iter().filter(|u| u.starts_with(&format!("{solver}."))).collect();
                let known = known.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(", ");
                return Err(SolverError::Setting {
                    key: k.clone(),
                    reason: format!("unknown setting for solver {solver}; known: {known}"),
                });
            }
        }
        Ok(())
    }
}
