//! Typed access to every field of a preset, with its path, unit and physical range.
//!
//! Each preset section implements [`Fields`]: it walks its own fields, handing each to a
//! [`Visitor`] as a typed `&mut` reference with its metadata. That one list serves
//! - validation: every number is finite and inside its range ([`range_errors`]);
//! - `--set PATH=VALUE`: the path finds the field, the text is parsed for its type
//!   ([`Preset::set`]);
//! - the workbench: each section's editor is drawn from the same walk, so the compiler
//!   checks the way from a widget to its field, and a renamed field breaks the build, not a
//!   user's session;
//! - the property tests, which try extreme values in every numeric field.
//!
//! Paths use one dialect: `axes.x.servo.kp_per_s`, `cross.0.points`,
//! `crossbeam.posts.1.weight_n`, `scenario.plc_events.0.t_s`.

use super::{FieldError, Preset, PresetError};

/// A number with a unit and the range a real machine can have.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num {
    /// Unit as shown next to the field ("" for a ratio).
    pub unit: &'static str,
    /// Smallest allowed value.
    pub lo: f64,
    /// True when `lo` itself is not allowed (a quantity that must be > lo).
    pub lo_open: bool,
    /// Largest allowed value.
    pub hi: f64,
}

impl Num {
    /// `lo ≤ x ≤ hi`.
    pub const fn closed(unit: &'static str, lo: f64, hi: f64) -> Num {
        Num {
            unit,
            lo,
            lo_open: false,
            hi,
        }
    }

    /// `lo < x ≤ hi`.
    pub const fn above(unit: &'static str, lo: f64, hi: f64) -> Num {
        Num {
            unit,
            lo,
            lo_open: true,
            hi,
        }
    }

    /// Whether `x` is finite and inside the range.
    pub fn accepts(&self, x: f64) -> bool {
        x.is_finite() && x <= self.hi && (x > self.lo || (!self.lo_open && x == self.lo))
    }

    /// The range as text, e.g. `> 0 … 1000 mm`.
    pub fn describe(&self) -> String {
        let lo = if self.lo_open {
            format!("> {}", self.lo)
        } else {
            format!("{}", self.lo)
        };
        if self.unit.is_empty() {
            format!("{lo} … {}", self.hi)
        } else {
            format!("{lo} … {} {}", self.hi, crate::units::symbol(self.unit))
        }
    }

    /// The finding for a value outside the range, or None.
    pub fn reason(&self, x: f64) -> Option<String> {
        if self.accepts(x) {
            None
        } else if !x.is_finite() {
            Some(format!(
                "{x} is not a finite number (allowed: {})",
                self.describe()
            ))
        } else {
            Some(format!(
                "{} is outside the allowed range {}",
                short(x),
                self.describe()
            ))
        }
    }
}

/// A number for a message: full precision when short, otherwise 6 significant digits, so
/// that no 300-digit number reaches the terminal.
pub fn short(x: f64) -> String {
    let s = format!("{x}");
    if s.len() <= 16 { s } else { format!("{x:.6e}") }
}

/// A whole number with its range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Count {
    /// Smallest allowed value.
    pub lo: u64,
    /// Largest allowed value.
    pub hi: u64,
}

impl Count {
    /// The finding for a value outside the range, or None.
    pub fn reason(&self, n: u64) -> Option<String> {
        (!(self.lo..=self.hi).contains(&n))
            .then(|| format!("{n} is outside the allowed range {} … {}", self.lo, self.hi))
    }
}

/// A point table `(x, y)`: its units and ranges, how many points it may have, and how
/// many it needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TableSpec {
    /// Range of the x column.
    pub x: Num,
    /// Range of the y column.
    pub y: Num,
    /// Fewest points the table needs when it is in use.
    pub min_points: usize,
    /// Most points it may have.
    pub max_points: usize,
}

/// An enum chosen by name: the names are the ones preset files use.
pub trait Choice {
    /// Every allowed name, in display order.
    fn options(&self) -> &'static [&'static str];
    /// The current name.
    fn current(&self) -> &'static str;
    /// Switches to `name`; false if it is not one of [`Choice::options`].
    fn select(&mut self, name: &str) -> bool;
}

/// Implements [`Choice`] plus `name()`/`from_name()` for a plain enum whose preset names are
/// given, so the names live in one place.
#[macro_export]
macro_rules! choice_enum {
    ($t:ty { $($v:ident => $n:literal),+ $(,)? }) => {
        impl $t {
            /// Every preset name of this enum, in display order.
            pub const NAMES: &'static [&'static str] = &[$($n),+];
            /// The name used in preset files and on the command line.
            pub fn name(self) -> &'static str {
                match self { $(<$t>::$v => $n),+ }
            }
            /// The value called `s` in preset files, if any.
            pub fn from_name(s: &str) -> Option<$t> {
                match s.trim() { $($n => Some(<$t>::$v),)+ _ => None }
            }
        }
        impl $crate::preset::fields::Choice for $t {
            fn options(&self) -> &'static [&'static str] { <$t>::NAMES }
            fn current(&self) -> &'static str { self.name() }
            fn select(&mut self, name: &str) -> bool {
                match <$t>::from_name(name) { Some(v) => { *self = v; true } None => false }
            }
        }
    };
}

/// A value edited as RON text (lists of structs, lists of names).
pub trait RonValue {
    /// The value as RON text.
    fn to_ron_text(&self) -> String;
    /// Replaces the value by the RON text `s`; the error says why it does not parse.
    fn set_ron_text(&mut self, s: &str) -> Result<(), String>;
}

impl<T> RonValue for Vec<T>
where
    T: serde::Serialize + serde::de::DeserializeOwned,
{
    fn to_ron_text(&self) -> String {
        ron::to_string(self).unwrap_or_default()
    }
    fn set_ron_text(&mut self, s: &str) -> Result<(), String> {
        *self = ron::from_str(s).map_err(|e| format!("not a valid list: {e}"))?;
        Ok(())
    }
}

/// One field, typed, with its metadata.
pub enum Field<'a> {
    /// A number.
    Num(&'a mut f64, Num),
    /// A number that may be absent (`none`).
    OptNum(&'a mut Option<f64>, Num),
    /// A whole number.
    Count(&'a mut u32, Count),
    /// An index (a channel number).
    Index(&'a mut usize, Count),
    /// On/off.
    Flag(&'a mut bool),
    /// One of a set of names.
    Choice(&'a mut dyn Choice),
    /// A point table.
    Table(&'a mut Vec<(f64, f64)>, TableSpec),
    /// An increasing list of times.
    Times(&'a mut Vec<f64>, Num, usize),
    /// Free text (a name, a file, a mapping).
    Text(&'a mut String),
    /// Free text that may be absent (`none`).
    OptText(&'a mut Option<String>),
    /// A program address letter.
    Letter(&'a mut char),
    /// A list set as a whole from RON text.
    Ron(&'a mut dyn RonValue),
}

/// Receives every field of a walk.
pub trait Visitor {
    /// One field: its full path, its label for a form, the field, and whether it matters
    /// in the current configuration (a distance-mode count is irrelevant in lump mode; the
    /// workbench hides it, validation still checks it).
    fn field(&mut self, path: &str, label: &'static str, f: Field<'_>, relevant: bool);
}

/// Walks fields, keeping the path.
pub struct Walker<'v> {
    path: String,
    relevant: bool,
    v: &'v mut dyn Visitor,
}

impl<'v> Walker<'v> {
    /// A walk starting at `path` ("" for the preset root).
    pub fn new(path: &str, v: &'v mut dyn Visitor) -> Walker<'v> {
        Walker {
            path: path.to_owned(),
            relevant: true,
            v,
        }
    }

    /// The path of the section being walked.
    pub fn path(&self) -> &str {
        &self.path
    }

    fn leaf(&mut self, name: &str, label: &'static str, f: Field<'_>) {
        let len = self.path.len();
        if !self.path.is_empty() {
            self.path.push('.');
        }
        self.path.push_str(name);
        self.v.field(&self.path, label, f, self.relevant);
        self.path.truncate(len);
    }

    /// A number.
    pub fn num(&mut self, name: &str, label: &'static str, x: &mut f64, r: Num) {
        self.leaf(name, label, Field::Num(x, r));
    }

    /// A number that may be absent.
    pub fn opt_num(&mut self, name: &str, label: &'static str, x: &mut Option<f64>, r: Num) {
        self.leaf(name, label, Field::OptNum(x, r));
    }

    /// A whole number.
    pub fn count(&mut self, name: &str, label: &'static str, n: &mut u32, lo: u64, hi: u64) {
        self.leaf(name, label, Field::Count(n, Count { lo, hi }));
    }

    /// An index.
    pub fn index(&mut self, name: &str, label: &'static str, n: &mut usize, lo: u64, hi: u64) {
        self.leaf(name, label, Field::Index(n, Count { lo, hi }));
    }

    /// On/off.
    pub fn flag(&mut self, name: &str, label: &'static str, b: &mut bool) {
        self.leaf(name, label, Field::Flag(b));
    }

    /// One of a set of names.
    pub fn choice(&mut self, name: &str, label: &'static str, c: &mut dyn Choice) {
        self.leaf(name, label, Field::Choice(c));
    }

    /// A point table.
    pub fn table(
        &mut self,
        name: &str,
        label: &'static str,
        t: &mut Vec<(f64, f64)>,
        spec: TableSpec,
    ) {
        self.leaf(name, label, Field::Table(t, spec));
    }

    /// An increasing list of times.
    pub fn times(&mut self, name: &str, label: &'static str, t: &mut Vec<f64>, r: Num, max: usize) {
        self.leaf(name, label, Field::Times(t, r, max));
    }

    /// Free text.
    pub fn text(&mut self, name: &str, label: &'static str, s: &mut String) {
        self.leaf(name, label, Field::Text(s));
    }

    /// Free text that may be absent.
    pub fn opt_text(&mut self, name: &str, label: &'static str, s: &mut Option<String>) {
        self.leaf(name, label, Field::OptText(s));
    }

    /// A program address letter.
    pub fn letter(&mut self, name: &str, label: &'static str, c: &mut char) {
        self.leaf(name, label, Field::Letter(c));
    }

    /// A list set as a whole.
    pub fn ron(&mut self, name: &str, label: &'static str, v: &mut dyn RonValue) {
        self.leaf(name, label, Field::Ron(v));
    }

    /// The fields of a sub-section under `name`.
    pub fn nest(&mut self, name: &str, f: impl FnOnce(&mut Walker<'_>)) {
        let len = self.path.len();
        if !self.path.is_empty() {
            self.path.push('.');
        }
        self.path.push_str(name);
        f(self);
        self.path.truncate(len);
    }

    /// Fields that only matter when `cond` holds.
    pub fn when(&mut self, cond: bool, f: impl FnOnce(&mut Walker<'_>)) {
        let was = self.relevant;
        self.relevant = was && cond;
        f(self);
        self.relevant = was;
    }
}

/// A preset section whose fields can be walked.
pub trait Fields {
    /// Hands each field to the walker.
    fn fields(&mut self, w: &mut Walker<'_>);

    /// Rules between fields of this section (a breakaway force below the Coulomb level, a
    /// step that would make an explicit integrator unstable…), as findings under `at`.
    fn rules(&self, _at: &str, _out: &mut Vec<FieldError>) {}

    /// Every finding for this section: each field in its range, then the rules.
    fn check(&self, at: &str) -> Vec<FieldError>
    where
        Self: Clone,
    {
        let mut copy = self.clone();
        let mut out = range_errors(&mut copy, at);
        self.rules(at, &mut out);
        out
    }
}

/// Collects the range findings of a walk.
#[derive(Default)]
struct RangeCheck {
    errors: Vec<FieldError>,
}

impl RangeCheck {
    fn push(&mut self, path: &str, reason: String) {
        self.errors.push(FieldError {
            path: path.to_owned(),
            reason,
        });
    }

    fn table(&mut self, path: &str, t: &[(f64, f64)], spec: &TableSpec) {
        if t.len() > spec.max_points {
            self.push(
                path,
                format!(
                    "{} points; at most {} are allowed",
                    t.len(),
                    spec.max_points
                ),
            );
            return;
        }
        for (i, &(x, y)) in t.iter().enumerate() {
            if let Some(r) = spec.x.reason(x) {
                self.push(&format!("{path}.{i}"), format!("x: {r}"));
            }
            if let Some(r) = spec.y.reason(y) {
                self.push(&format!("{path}.{i}"), format!("y: {r}"));
            }
            if i > 0 && x.is_finite() && t[i - 1].0.is_finite() && x <= t[i - 1].0 {
                self.push(
                    &format!("{path}.{i}"),
                    format!(
                        "x = {} is not greater than the previous x = {}; x must be strictly increasing",
                        short(x),
                        short(t[i - 1].0)
                    ),
                );
            }
        }
    }
}

impl Visitor for RangeCheck {
    fn field(&mut self, path: &str, _label: &'static str, f: Field<'_>, _relevant: bool) {
        match f {
            Field::Num(x, r) => {
                if let Some(reason) = r.reason(*x) {
                    self.push(path, reason);
                }
            }
            Field::OptNum(Some(x), r) => {
                if let Some(reason) = r.reason(*x) {
                    self.push(path, reason);
                }
            }
            Field::Count(n, c) => {
                if let Some(reason) = c.reason(u64::from(*n)) {
                    self.push(path, reason);
                }
            }
            Field::Index(n, c) => {
                if let Some(reason) = c.reason(*n as u64) {
                    self.push(path, reason);
                }
            }
            Field::Table(t, spec) => self.table(path, t, &spec),
            Field::Times(t, r, max) => {
                if t.len() > max {
                    self.push(path, format!("{} entries; at most {max}", t.len()));
                    return;
                }
                for (i, &x) in t.iter().enumerate() {
                    if let Some(reason) = r.reason(x) {
                        self.push(&format!("{path}.{i}"), reason);
                    } else if i > 0 && x <= t[i - 1] {
                        self.push(&format!("{path}.{i}"), "times must increase".into());
                    }
                }
            }
            _ => {}
        }
    }
}

/// The range findings of every field of `s`, with paths under `at`.
pub fn range_errors(s: &mut dyn FieldsDyn, at: &str) -> Vec<FieldError> {
    let mut rc = RangeCheck::default();
    s.walk(&mut Walker::new(at, &mut rc));
    rc.errors
}

/// [`Fields`] without the `Clone` bound, so a section can be walked through `&mut dyn`.
pub trait FieldsDyn {
    /// Walks the fields.
    fn walk(&mut self, w: &mut Walker<'_>);
}

impl<T: Fields> FieldsDyn for T {
    fn walk(&mut self, w: &mut Walker<'_>) {
        self.fields(w);
    }
}

/// Sets one field from text.
struct Setter<'a> {
    path: &'a str,
    value: &'a str,
    found: bool,
    error: Option<String>,
    paths: Vec<String>,
}

fn parse_num(s: &str) -> Result<f64, String> {
    s.trim()
        .parse::<f64>()
        .map_err(|_| format!("'{s}' is not a number"))
}

fn parse_count(s: &str) -> Result<u64, String> {
    s.trim()
        .parse::<u64>()
        .map_err(|_| format!("'{s}' is not a whole number ≥ 0"))
}

fn is_none(s: &str) -> bool {
    matches!(s.trim(), "none" | "None")
}

/// Parses `text` for the field `f` and stores it; the error says what was expected.
pub fn set_from_text(f: Field<'_>, text: &str) -> Result<(), String> {
    match f {
        Field::Num(x, _) => *x = parse_num(text)?,
        Field::OptNum(x, _) => {
            *x = if is_none(text) {
                None
            } else {
                Some(parse_num(text)?)
            }
        }
        Field::Count(n, c) => {
            let v = parse_count(text)?;
            if let Some(r) = c.reason(v) {
                return Err(r);
            }
            *n = u32::try_from(v).map_err(|_| format!("{v} is too large"))?;
        }
        Field::Index(n, c) => {
            let v = parse_count(text)?;
            if let Some(r) = c.reason(v) {
                return Err(r);
            }
            *n = usize::try_from(v).map_err(|_| format!("{v} is too large"))?;
        }
        Field::Flag(b) => {
            *b = match text.trim() {
                "true" | "on" | "1" | "yes" => true,
                "false" | "off" | "0" | "no" => false,
                other => return Err(format!("'{other}' is not true or false")),
            }
        }
        Field::Choice(c) => {
            if !c.select(text.trim()) {
                return Err(format!(
                    "'{}' is not one of: {}",
                    text.trim(),
                    c.options().join(", ")
                ));
            }
        }
        Field::Table(t, _) => {
            *t = ron::from_str(text)
                .map_err(|e| format!("not a point table like [(0.0, 0.0), (100.0, 2.5)]: {e}"))?;
        }
        Field::Times(t, _, _) => {
            *t = ron::from_str(text)
                .map_err(|e| format!("not a list of times like [600.0, 1200.0]: {e}"))?;
        }
        Field::Text(s) => *s = text.to_owned(),
        Field::OptText(s) => *s = (!is_none(text)).then(|| text.to_owned()),
        Field::Letter(c) => {
            let mut it = text.trim().chars();
            match (it.next(), it.next()) {
                (Some(ch), None) => *c = ch,
                _ => return Err(format!("'{text}' is not a single letter")),
            }
        }
        Field::Ron(v) => v.set_ron_text(text)?,
    }
    Ok(())
}

impl Visitor for Setter<'_> {
    fn field(&mut self, path: &str, _label: &'static str, f: Field<'_>, _relevant: bool) {
        if self.found {
            return;
        }
        if path != self.path {
            self.paths.push(path.to_owned());
            return;
        }
        self.found = true;
        if let Err(e) = set_from_text(f, self.value) {
            self.error = Some(e);
        }
    }
}

/// Lists every path of a walk.
struct Lister {
    out: Vec<(String, Option<Num>)>,
}

impl Visitor for Lister {
    fn field(&mut self, path: &str, _label: &'static str, f: Field<'_>, _relevant: bool) {
        let num = match f {
            Field::Num(_, r) | Field::OptNum(_, r) => Some(r),
            _ => None,
        };
        self.out.push((path.to_owned(), num));
    }
}

/// Every field of a walk as (path, exact value, value as a user reads it): the exact text
/// decides whether two fields differ, so a change below the shown precision still shows.
struct Values {
    out: Vec<(String, String, String)>,
}

impl Visitor for Values {
    fn field(&mut self, path: &str, _label: &'static str, f: Field<'_>, _relevant: bool) {
        use crate::units::{fmt_num, fmt_qty, symbol};
        let (exact, shown) = match f {
            Field::Num(x, r) => (format!("{x:?}"), fmt_qty(*x, r.unit)),
            Field::OptNum(x, r) => (
                format!("{x:?}"),
                x.map_or_else(|| "none".to_owned(), |x| fmt_qty(x, r.unit)),
            ),
            Field::Count(n, _) => (n.to_string(), n.to_string()),
            Field::Index(n, _) => (n.to_string(), n.to_string()),
            Field::Flag(b) => (b.to_string(), if *b { "on" } else { "off" }.to_owned()),
            Field::Choice(c) => (c.current().to_owned(), c.current().to_owned()),
            Field::Table(t, spec) => (
                format!("{t:?}"),
                format!(
                    "{} points ({}, {}): {}",
                    t.len(),
                    symbol(spec.x.unit),
                    symbol(spec.y.unit),
                    t.iter()
                        .map(|(x, y)| format!("({}, {})", fmt_num(*x), fmt_num(*y)))
                        .collect::<Vec<_>>()
                        .join(" ")
                ),
            ),
            Field::Times(t, r, _) => (
                format!("{t:?}"),
                t.iter()
                    .map(|x| fmt_qty(*x, r.unit))
                    .collect::<Vec<_>>()
                    .join(", "),
            ),
            Field::Text(s) => (s.clone(), s.clone()),
            Field::OptText(s) => (
                format!("{s:?}"),
                s.clone().unwrap_or_else(|| "none".to_owned()),
            ),
            Field::Letter(c) => (c.to_string(), c.to_string()),
            Field::Ron(v) => (v.to_ron_text(), v.to_ron_text()),
        };
        self.out.push((path.to_owned(), exact, shown));
    }
}

/// One field that differs between two presets: its path and both values as shown.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldChange {
    /// The field's path (`axes.x.servo.kp_per_s`).
    pub path: String,
    /// Its value before ("—" when the field does not exist there).
    pub before: String,
    /// Its value after ("—" when the field does not exist there).
    pub after: String,
}

impl Preset {
    /// Every field as (path, exact value, value as a user reads it), in walk order.
    fn field_values(&self) -> Vec<(String, String, String)> {
        let mut v = Values { out: vec![] };
        self.clone().fields(&mut Walker::new("", &mut v));
        v.out
    }

    /// The fields that differ from `self` to `other`, field by field (what an Apply will
    /// change), in walk order, each with both values as a user reads them.
    pub fn diff(&self, other: &Preset) -> Vec<FieldChange> {
        let a = self.field_values();
        let b = other.field_values();
        let find = |list: &[(String, String, String)], p: &str| {
            list.iter()
                .find(|(q, _, _)| q == p)
                .map(|(_, e, s)| (e.clone(), s.clone()))
        };
        let mut out: Vec<FieldChange> = a
            .iter()
            .filter_map(|(p, ea, sa)| {
                let other = find(&b, p);
                let same = other.as_ref().is_some_and(|(eb, _)| eb == ea);
                (!same).then(|| FieldChange {
                    path: p.clone(),
                    before: sa.clone(),
                    after: other.map_or_else(|| "—".to_owned(), |(_, sb)| sb),
                })
            })
            .collect();
        out.extend(
            b.iter()
                .filter(|(p, _, _)| !a.iter().any(|(q, _, _)| q == p))
                .map(|(p, _, sb)| FieldChange {
                    path: p.clone(),
                    before: "—".to_owned(),
                    after: sb.clone(),
                }),
        );
        out
    }

    /// Sets the field at `path` (`axes.x.servo.kp_per_s`) from `value`, then checks the
    /// whole preset's data. Numbers are plain decimals; enums take their preset names
    /// (`lump`); lists and tables are RON (`[(0.0, 0.0), (100.0, 2.5)]`, `["a.ngc"]`).
    pub fn set(&self, path: &str, value: &str) -> Result<Preset, PresetError> {
        let oerr = |reason: String| PresetError::Override {
            path: path.to_owned(),
            reason,
        };
        let mut p = self.clone();
        let mut s = Setter {
            path,
            value,
            found: false,
            error: None,
            paths: vec![],
        };
        p.fields(&mut Walker::new("", &mut s));
        if let Some(e) = s.error {
            return Err(oerr(e));
        }
        if !s.found {
            return Err(oerr(unknown_path(path, &s.paths)));
        }
        let errors = p.validate();
        if errors.is_empty() {
            return Ok(p);
        }
        // The field set is the usual culprit: its findings alone, without the path again.
        let own: Vec<&FieldError> = errors.iter().filter(|e| e.path == path).collect();
        Err(oerr(if own.len() == errors.len() {
            own.iter()
                .map(|e| e.reason.as_str())
                .collect::<Vec<_>>()
                .join("; ")
        } else {
            format!("the preset is then invalid:\n{}", super::list(&errors))
        }))
    }

    /// Every field path of this preset, with the range of the numeric ones.
    pub fn field_paths(&self) -> Vec<(String, Option<Num>)> {
        let mut l = Lister { out: vec![] };
        self.clone().fields(&mut Walker::new("", &mut l));
        l.out
    }
}

/// Why `path` names no field: the fields that share its longest known prefix.
fn unknown_path(path: &str, known: &[String]) -> String {
    let mut prefix = path;
    loop {
        let under: Vec<&str> = known
            .iter()
            .filter(|k| prefix.is_empty() || k.starts_with(&format!("{prefix}.")))
            .map(|k| k.as_str())
            .collect();
        if !under.is_empty() {
            let shown: Vec<&str> = under
                .iter()
                .map(|k| {
                    let rest = if prefix.is_empty() {
                        k
                    } else {
                        &k[prefix.len() + 1..]
                    };
                    rest.split('.').next().unwrap_or(rest)
                })
                .fold(Vec::new(), |mut v, s| {
                    if !v.contains(&s) {
                        v.push(s);
                    }
                    v
                });
            let here = if prefix.is_empty() {
                "the preset"
            } else {
                prefix
            };
            return format!(
                "no field '{path}'; {here} has: {}",
                shown
                    .iter()
                    .take(40)
                    .copied()
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        match prefix.rfind('.') {
            Some(i) => prefix = &prefix[..i],
            None if !prefix.is_empty() => prefix = "",
            None => return format!("no field '{path}'"),
        }
    }
}
