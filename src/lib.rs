//! axisbench: a simulated CNC feed-axis machine (NC, amplifier, plant, structure) for tuning
//! and teaching compensation functions, and for diagnosing where a model disagrees with a
//! measured machine. This crate is the model; it knows nothing of the GUI.
//!
//! Data flows one way, the way the machine does:
//! program → [`nc`] (parse, interpolate, acc/dec, modes) → [`comp`] (position corrections)
//! → [`servo`] (position/velocity loops, torque) → [`plant`] → [`trace`].
//! [`machine::Machine`] wires one period T3 of all of it.
#![warn(missing_docs)]

pub mod analysis;
pub mod bench;
pub mod comp;
pub mod diagnose;
pub mod drive;
pub mod evaluation;
pub mod export;
pub mod fsutil;
pub mod indep;
pub mod machine;
pub mod measure;
pub mod nc;
pub mod plant;
pub mod preset;
pub mod servo;
pub mod signal;
pub mod table;
pub mod trace;
pub mod tune;
pub mod units;

pub use machine::{Machine, MachineError};
pub use preset::{LoadedPreset, Preset};
pub use trace::Trace;
