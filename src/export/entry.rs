//! The one list every export is made of.
//!
//! A target turns the preset into a list of [`Entry`]s: each names the preset field it
//! comes from (dot dialect, `axes.x.backlash.q_um`), its value with unit, how faithfully the
//! controller carries it ([`Status`]) and the lines it becomes ([`Put`]). The files are
//! rendered from those lines ([`Plan::render`]) and the mapping report from the same
//! entries, so a report can never claim a value the files do not hold, and a file can hold
//! no value the report does not account for (only layout — file headers, section headers —
//! is not an entry).

use serde::Serialize;

use super::Violation;
use super::report::{ErrFigures, Pending};

/// How faithfully the controller carries a preset setting.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// Carried exactly.
    Mapped,
    /// Computed from preset settings by a documented rule.
    Derived,
    /// Carried, but the target's behaviour differs; the error is given.
    Approximated,
    /// The target cannot carry it; the nearest approximation and its error are given.
    NotRepresentable,
    /// The target may have such a function, but no parameter number is documented here.
    NoDocumentedParameter,
}

impl Status {
    /// The label the report prints.
    pub fn label(self) -> &'static str {
        match self {
            Status::Mapped => "mapped",
            Status::Derived => "derived",
            Status::Approximated => "approximated",
            Status::NotRepresentable => "not representable",
            Status::NoDocumentedParameter => "no documented parameter",
        }
    }
}

/// Where (part of) an entry's value lands: one line of one written file.
///
/// A line is identified by its file, section and key; several entries may write onto one
/// line (FANUC writes one `A<n> P<value>` word per axis after the parameter number, a
/// HEIDENHAIN table row gets one cell per compensated axis), each contributing its `text`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Put {
    /// File name relative to the output folder.
    pub file: String,
    /// The header line of the section the line sits in (`[JOINT_0]`, `; axis 'x'`); empty
    /// for none. Written once, before the section's first line.
    pub section: String,
    /// The start of the line, which identifies it within its section (`BACKLASH = `,
    /// `N1851`, a table row number).
    pub key: String,
    /// What this entry writes on the line after the key.
    pub text: String,
}

impl Put {
    /// A line of `file` under `section`.
    pub fn new(
        file: impl Into<String>,
        section: impl Into<String>,
        key: impl Into<String>,
        text: impl Into<String>,
    ) -> Put {
        Put {
            file: file.into(),
            section: section.into(),
            key: key.into(),
            text: text.into(),
        }
    }

    /// The line as far as this entry writes it, for the report.
    fn describe(&self) -> String {
        let line = format!("{}{}", self.key, self.text);
        let line = line.trim();
        // A section header may carry a comment line before it: show the header itself.
        match self.section.lines().last() {
            Some(sec) if !sec.trim().is_empty() => format!("{} {line}", sec.trim()),
            _ => line.to_owned(),
        }
    }
}

/// One row of an export: a preset setting and what became of it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Entry {
    /// The preset field path, dot dialect as `--set` takes it (`axes.x.servo.kp_per_s`).
    pub field: String,
    /// The preset's value with its unit (`12.5 µm`, `distance (N = 4, B = 500 µm)`).
    pub value: String,
    /// How faithfully the controller carries it.
    pub status: Status,
    /// The file lines it becomes; empty when nothing is written for it.
    pub puts: Vec<Put>,
    /// The rule used, or the nearest approximation and why.
    pub note: String,
    /// The error an approximation introduces, when computed.
    pub error: Option<ErrFigures>,
}

impl Entry {
    /// `field = value`, as the report's first column shows it.
    pub fn setting(&self) -> String {
        format!("{} = {}", self.field, self.value)
    }

    /// Where the value went, rendered from [`Entry::puts`]: every line, or for a long
    /// table its first and last line and the count.
    pub fn target(&self) -> String {
        let mut files: Vec<(&str, Vec<&Put>)> = Vec::new();
        for p in &self.puts {
            match files.iter_mut().find(|(f, _)| *f == p.file) {
                Some((_, v)) => v.push(p),
                None => files.push((&p.file, vec![p])),
            }
        }
        let part = |(file, puts): &(&str, Vec<&Put>)| -> String {
            let lines: Vec<String> = puts.iter().map(|p| p.describe()).collect();
            if lines.len() <= 4 {
                format!("{file}: {}", lines.join("; "))
            } else {
                format!(
                    "{file}: {} lines, {} … {}",
                    lines.len(),
                    lines.first().map_or("", String::as_str),
                    lines.last().map_or("", String::as_str)
                )
            }
        };
        files.iter().map(part).collect::<Vec<_>>().join(" | ")
    }
}

/// The layout of one written file: what surrounds the entries' lines.
#[derive(Debug, Clone)]
pub struct FileSpec {
    /// File name relative to the output folder.
    pub name: String,
    /// Text before the first line (comments, a program header).
    pub head: String,
    /// Text after the last line.
    pub tail: String,
    /// An empty line before each section header (INI style).
    pub section_gap: bool,
    /// Written even when no entry puts a line into it.
    pub always: bool,
    /// Lines are concatenated as they are, without adding newlines (program text).
    pub raw: bool,
}

impl FileSpec {
    /// A file with this head and tail, written only when an entry puts a line into it.
    pub fn new(name: impl Into<String>, head: impl Into<String>, tail: impl Into<String>) -> Self {
        FileSpec {
            name: name.into(),
            head: head.into(),
            tail: tail.into(),
            section_gap: false,
            always: false,
            raw: false,
        }
    }

    /// Written even when empty.
    pub fn always(mut self) -> Self {
        self.always = true;
        self
    }

    /// An empty line before each section header.
    pub fn gaps(mut self) -> Self {
        self.section_gap = true;
        self
    }

    /// Contents taken verbatim from the entries (no newline handling).
    pub fn raw(mut self) -> Self {
        self.raw = true;
        self
    }
}

/// A rendered file and, per line, the entries that wrote on it.
#[derive(Debug, Clone)]
pub struct RenderedFile {
    /// File name relative to the output folder.
    pub name: String,
    /// The contents.
    pub text: String,
    /// For line n (1-based) at index n − 1: indices of the entries that wrote on it.
    pub owners: Vec<Vec<usize>>,
}

/// What a target produces before anything is simulated or written: its files' layout and
/// the one list of entries.
pub(crate) struct Plan {
    /// The files the target writes, in order.
    pub files: Vec<FileSpec>,
    /// The one list: every file line comes from one of these.
    pub entries: Vec<Pending>,
}

/// One line being assembled: its key, the entries' texts, and who wrote them.
struct Line<'a> {
    key: &'a str,
    texts: Vec<&'a str>,
    owners: Vec<usize>,
}

impl Plan {
    /// Renders every file from the entries' lines, in the order the entries first mention
    /// sections and lines. A line for a file the plan does not declare is an internal
    /// error, not a silently dropped value.
    pub fn render(&self) -> Result<Vec<RenderedFile>, Vec<Violation>> {
        let bad: Vec<Violation> = self
            .entries
            .iter()
            .flat_map(|p| p.entry.puts.iter().map(move |put| (p, put)))
            .filter(|(_, put)| !self.files.iter().any(|f| f.name == put.file))
            .map(|(p, put)| {
                Violation::new(
                    &p.entry.field,
                    format!(
                        "internal: a line for {}, which this target does not write",
                        put.file
                    ),
                )
            })
            .collect();
        if !bad.is_empty() {
            return Err(bad);
        }
        Ok(self
            .files
            .iter()
            .filter_map(|spec| self.render_file(spec))
            .collect())
    }

    fn render_file(&self, spec: &FileSpec) -> Option<RenderedFile> {
        // Sections in first-mention order, each with its lines in first-mention order.
        let mut sections: Vec<(&str, Vec<Line>)> = Vec::new();
        for (i, p) in self.entries.iter().enumerate() {
            for put in p.entry.puts.iter().filter(|put| put.file == spec.name) {
                let si = match sections.iter().position(|(s, _)| *s == put.section) {
                    Some(si) => si,
                    None => {
                        sections.push((&put.section, Vec::new()));
                        sections.len() - 1
                    }
                };
                let lines = &mut sections[si].1;
                match lines.iter_mut().find(|l| l.key == put.key) {
                    Some(l) => {
                        l.texts.push(&put.text);
                        if !l.owners.contains(&i) {
                            l.owners.push(i);
                        }
                    }
                    None => lines.push(Line {
                        key: &put.key,
                        texts: vec![&put.text],
                        owners: vec![i],
                    }),
                }
            }
        }
        if sections.is_empty() && !spec.always {
            return None;
        }
        let mut out = Assembler::new(spec.raw);
        out.push(&spec.head, &[]);
        for (section, lines) in &sections {
            if !section.is_empty() {
                if spec.section_gap {
                    out.push("\n", &[]);
                }
                out.push(&format!("{section}\n"), &[]);
            }
            for l in lines {
                let text = format!("{}{}", l.key, l.texts.concat());
                out.push_line(&text, &l.owners);
            }
        }
        out.push(&spec.tail, &[]);
        Some(RenderedFile {
            name: spec.name.clone(),
            text: out.text,
            owners: out.owners,
        })
    }
}

/// Builds a file's text and its per-line owner table together.
struct Assembler {
    raw: bool,
    text: String,
    owners: Vec<Vec<usize>>,
}

impl Assembler {
    fn new(raw: bool) -> Self {
        Assembler {
            raw,
            text: String::new(),
            owners: Vec::new(),
        }
    }

    /// Appends text whose lines belong to `owners`.
    fn push(&mut self, s: &str, owners: &[usize]) {
        for _ in 0..s.matches('\n').count() {
            self.owners.push(owners.to_vec());
        }
        self.text += s;
    }

    /// Appends a line (a newline is added unless the file is raw or it has one).
    fn push_line(&mut self, s: &str, owners: &[usize]) {
        if self.raw || s.ends_with('\n') {
            self.push(s, owners);
        } else {
            self.push(&format!("{s}\n"), owners);
        }
        if self.raw && !s.ends_with('\n') {
            // A raw file's last line without a newline still has an owner.
            self.owners.push(owners.to_vec());
        }
    }
}

/// Converts a validator path (`axes[x].servo`, `cross[0].points[1]`) to the dot dialect
/// `--set` takes and every message uses (`axes.x.servo`, `cross.0.points.1`).
pub fn dot_path(path: &str) -> String {
    path.replace('[', ".").replace(']', "")
}

/// A number for a message: shortest round-trip form, with an exponent where the plain form
/// would be unreadable (1e300, 1e-12).
pub fn show(x: f64) -> String {
    let a = x.abs();
    if x != 0.0 && x.is_finite() && !(0.000_001..1e15).contains(&a) {
        format!("{x:e}")
    } else {
        super::num(x)
    }
}

/// A value with its unit, for [`Entry::value`].
pub fn with_unit(x: f64, unit: &str) -> String {
    if unit.is_empty() {
        show(x)
    } else {
        format!("{} {unit}", show(x))
    }
}
